"""Runs gcode-feedopt's Cura script inside the real Cura 4.13 PostProcessingPlugin Script class
and Uranium's real ContainerRegistry/ContainerStack (Debian's cura, /usr/bin/python3).

Only the Qt event loop is stood in for (deferred calls run at once). Usage:
    /usr/bin/python3 cura_driver.py SCRIPT.py LAYERS.json OUT.json key=value ...
"""

import importlib.machinery
import json
import sys

sys.path.insert(0, "/usr/lib/cura/plugins")

import UM.Settings.ContainerStack  # noqa: E402
import UM.Settings.InstanceContainer  # noqa: E402
from UM.Settings.ContainerRegistry import ContainerRegistry  # noqa: E402
from UM.VersionUpgradeManager import VersionUpgradeManager  # noqa: E402


class _Loop:
    def callLater(self, f, *a, **k):
        f(*a, **k)


VersionUpgradeManager(_Loop())
_reg = ContainerRegistry(_Loop())
UM.Settings.InstanceContainer.setContainerRegistry(_reg)
UM.Settings.ContainerStack.setContainerRegistry(_reg)

script_path, layers_path, out_path, *settings = sys.argv[1:]
mod = importlib.machinery.SourceFileLoader("PostProcessingPlugin.scripts.GcodeFeedopt",
                                           script_path).load_module()
script = mod.GcodeFeedopt()
script.initialize()
for kv in settings:
    key, value = kv.split("=", 1)
    script._instance.setProperty(key, "value", value)
data = json.load(open(layers_path))
result = script.execute(data)
json.dump({"result": result, "machine": script.getSettingValueByKey("machine")}, open(out_path, "w"))
