"""The Cura script in the real Cura 4.13 Script class and Uranium (Debian's cura package)."""

import json
import pathlib
import shutil
import subprocess
import sys

import pytest

import gcode_feedopt
from gcode_feedopt.pipeline import Options, optimize_file
from gcode_feedopt.profile import load_profile

from ..conftest import GCODE_DIR

pytestmark = pytest.mark.host
CURA_SCRIPT = pathlib.Path("/usr/lib/cura/plugins/PostProcessingPlugin/Script.py")
SYS_PY = "/usr/bin/python3"
SCRIPT = pathlib.Path(gcode_feedopt.__file__).parent / "hosts" / "GcodeFeedopt.py"
DRIVER = pathlib.Path(__file__).with_name("cura_driver.py")


def cura_layers(text: str) -> list[str]:
    """Cut a Cura G-code into Cura's layer list: header, then one chunk per ;LAYER:."""
    chunks, cur = [], []
    for line in text.splitlines(keepends=True):
        if line.startswith(";LAYER:") and cur:
            chunks.append("".join(cur))
            cur = []
        cur.append(line)
    chunks.append("".join(cur))
    return chunks


def run_script(tmp_path, layers, **settings):
    lp, op = tmp_path / "layers.json", tmp_path / "out.json"
    lp.write_text(json.dumps(layers))
    cli = str(pathlib.Path(sys.executable).parent / "gcode-feedopt")
    args = [SYS_PY, str(DRIVER), str(SCRIPT), str(lp), str(op), f"command={cli}"]
    args += [f"{k}={v}" for k, v in settings.items()]
    r = subprocess.run(args, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(op.read_text())


@pytest.mark.skipif(not CURA_SCRIPT.exists(), reason="Debian cura not installed (.ci/run installs it)")
def test_cura_script_returns_the_same_layer_shape(tmp_path):
    text = (GCODE_DIR / "cura-4.8_ender3_square-tower.gcode").read_text()
    layers = cura_layers(text)
    got = run_script(tmp_path, layers)
    out = got["result"]
    assert got["machine"] == "ender3pro"
    assert len(out) == len(layers)
    for a, b in zip(layers[1:], out[1:]):
        assert b.splitlines()[0] == a.splitlines()[0]  # each layer starts with its ;LAYER:
    # exactly what the CLI makes of the joined file (which verify checked before writing)
    src = tmp_path / "joined.gcode"
    src.write_text("".join(layers))
    ref = tmp_path / "ref.gcode"
    optimize_file(src, ref, load_profile("ender3pro"), Options())
    assert "".join(out) == ref.read_text()


@pytest.mark.skipif(not CURA_SCRIPT.exists(), reason="Debian cura not installed (.ci/run installs it)")
def test_cura_script_failure_returns_data_unchanged(tmp_path):
    layers = cura_layers((GCODE_DIR / "cura-4.8_ender3_square-tower.gcode").read_text())[:5]
    got = run_script(tmp_path, layers, machine="no-such-printer")
    assert got["result"] == layers


@pytest.mark.skipif(not CURA_SCRIPT.exists(), reason="Debian cura not installed (.ci/run installs it)")
def test_cura_script_time_limit_stops_the_command_and_its_workers(tmp_path):
    """Issue 18: on its time limit the script stops gcode-feedopt and every worker it started
    (its own process group: SIGTERM, then SIGKILL) and gives Cura its G-code back unchanged."""
    import time

    layers = cura_layers((GCODE_DIR / "cura-4.11_ender3_3dbenchy.gcode").read_text())
    t0 = time.monotonic()
    got = run_script(tmp_path, layers, method="pidd", timeout_s=3)
    assert got["result"] == layers
    assert time.monotonic() - t0 < 60
    time.sleep(0.5)
    left = subprocess.run(["pgrep", "-f", "cura-feedopt-"], capture_output=True, text=True).stdout
    assert not left.strip(), f"processes left: {left}"
