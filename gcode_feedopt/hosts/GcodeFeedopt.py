# Cura post-processing script for gcode-feedopt.
#
# Put this file in Cura's scripts folder (Help > Show Configuration Folder, then
# scripts/; e.g. ~/.local/share/cura/<version>/scripts/ on Linux,
# %APPDATA%\cura\<version>\scripts\ on Windows), restart Cura, and add "Feedrate optimization
# (gcode-feedopt)" under Extensions > Post Processing > Modify G-Code. It runs the installed
# `gcode-feedopt` command on the joined layers and hands Cura back the same list of layers.
# On any failure it shows a message and returns the G-code unchanged.

import os
import signal
import subprocess
import tempfile

from ..Script import Script

try:
    from UM.Logger import Logger
except ImportError:  # pragma: no cover - outside Cura
    Logger = None

_MARK = ";GCODE_FEEDOPT_LAYER_END"


class GcodeFeedopt(Script):
    """Re-time the print with gcode-feedopt (the class is named as the file, as Cura needs)."""

    def getSettingDataString(self):
        return """{
            "name": "Feedrate optimization (gcode-feedopt)",
            "key": "GcodeFeedopt",
            "metadata": {},
            "version": 2,
            "settings": {
                "machine": {"label": "Machine profile", "description": "Built-in profile name (ender3pro, nomad3, voron24) or the path of a profile .yaml", "type": "str", "default_value": "ender3pro"},
                "tolerance": {"label": "Tolerance", "description": "Contour-error tolerance E_max", "unit": "mm", "type": "float", "default_value": 0.1, "minimum_value": "0.001"},
                "stringency": {"label": "Stringency", "description": "Fraction of samples that must stay within the tolerance", "type": "float", "default_value": 0.95, "minimum_value": "0.5", "maximum_value": "0.9999"},
                "method": {"label": "Method", "description": "Planner", "type": "enum", "options": {"pidd": "Digital twin (PIDD)", "kinematic": "Kinematic limits", "pb": "Physics only", "conservative": "Conservative"}, "default_value": "pidd"},
                "timeout_s": {"label": "Time limit", "description": "Stop gcode-feedopt (and its worker processes) after this long and keep the G-code unchanged", "unit": "s", "type": "int", "default_value": 3600, "minimum_value": "1"},
                "command": {"label": "gcode-feedopt command", "description": "Full path of the gcode-feedopt executable if it is not on PATH", "type": "str", "default_value": "gcode-feedopt"}
            }
        }"""

    def _fail(self, reason):
        text = "gcode-feedopt: " + reason + " (G-code left unchanged)"
        if Logger is not None:
            Logger.log("e", text)
        try:
            from UM.Message import Message
            Message(text, title="Feedrate optimization").show()
        except Exception:
            pass

    def execute(self, data):
        if not data:
            return data
        parts = []
        for chunk in data:
            parts.append(chunk if chunk.endswith("\n") else chunk + "\n")
            parts.append(_MARK + "\n")
        fd, path = tempfile.mkstemp(suffix=".gcode", prefix="cura-feedopt-")
        try:
            with os.fdopen(fd, "w", encoding="utf-8", newline="") as fh:
                fh.write("".join(parts))
            cmd = [self.getSettingValueByKey("command") or "gcode-feedopt", path,
                   "--machine", str(self.getSettingValueByKey("machine")),
                   "--tolerance", str(self.getSettingValueByKey("tolerance")),
                   "--stringency", str(self.getSettingValueByKey("stringency")),
                   "--method", str(self.getSettingValueByKey("method")), "--quiet"]
            limit = int(self.getSettingValueByKey("timeout_s") or 3600)
            # its own process group: on the time limit the command *and its workers* stop
            group = {"start_new_session": True} if os.name == "posix" else {}
            try:
                proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True, **group)
            except (OSError, subprocess.SubprocessError) as exc:
                self._fail("could not run " + cmd[0] + ": " + str(exc))
                return data
            try:
                out, err = proc.communicate(timeout=limit)
            except subprocess.TimeoutExpired:
                _stop(proc)
                self._fail("stopped after the time limit of %d s (raise it in the script's "
                           "settings, or use the kinematic method)" % limit)
                return data
            if proc.returncode != 0:
                lines = (err or out or "exit code %d" % proc.returncode).strip().splitlines()
                self._fail(lines[-1] if lines else "failed")
                return data
            with open(path, encoding="utf-8", newline="") as fh:
                text = fh.read()
        finally:
            try:
                os.unlink(path)
            except OSError:
                pass
        pieces = text.split(_MARK + "\n")
        if len(pieces) != len(data) + 1 or pieces[-1].strip():
            self._fail("the result does not split back into Cura's %d layers" % len(data))
            return data
        out = []
        for chunk, new in zip(data, pieces[:-1]):
            out.append(new if chunk.endswith("\n") else new[:-1])
        return out


def _stop(proc):
    """Stop ``proc`` and every process of its group: SIGTERM first (gcode-feedopt then stops
    its workers and leaves the file as it was), SIGKILL after 10 s."""
    if os.name != "posix":
        proc.kill()
        proc.wait()
        return
    for sig, wait in ((signal.SIGTERM, 10), (signal.SIGKILL, 10)):
        try:
            os.killpg(proc.pid, sig)
        except OSError:
            break
        try:
            proc.wait(timeout=wait)
            break
        except subprocess.TimeoutExpired:
            continue
    try:  # workers may outlive the leader by a moment: the group goes too
        os.killpg(proc.pid, signal.SIGKILL)
    except OSError:
        pass
    proc.communicate()
