"""The time written into the file is the time the summary reports (issue 18): the firmware
model's time of the written file, not the plan's (they part by a fraction of a percent)."""

from __future__ import annotations

import json
import re
import subprocess
import sys

import pytest

from gcode_feedopt.gcode.metadata import format_duration, rescale_times

from ..conftest import GCODE_DIR


def test_rescale_times_moves_every_time_line_and_nothing_else():
    data = (b";FLAVOR:Marlin\n;TIME:100\nG1 X1 F600\n;TIME_ELAPSED:50.000000\n"
            b"M73 P50 R1\n; estimated printing time (normal mode) = 1m 40s\r\nG1 X2\n")
    out = rescale_times(data, 100.0, 110.0).splitlines(keepends=True)
    assert out[0] == b";FLAVOR:Marlin\n" and out[2] == b"G1 X1 F600\n" and out[6] == b"G1 X2\n"
    assert out[1] == b";TIME:110\n"
    assert out[3] == b";TIME_ELAPSED:55.000000\n"
    assert out[4] == b"M73 P50 R1\n"        # 55 s left of 110 s: 1 minute
    assert out[5] == b"; estimated printing time (normal mode) = 1m 50s\r\n"
    assert rescale_times(data, 100.0, 100.0) is data


@pytest.mark.parametrize("name,lines,method", [
    ("cura-4.11_ender3_3dbenchy.gcode", 5000, "pidd"),
    ("prusaslicer-2.6.1_mini_3dbenchy.gcode", 6000, "pidd")])
def test_time_in_the_file_is_the_summary_time(name, lines, method, tmp_path):
    src = GCODE_DIR / name
    if not src.is_file():
        pytest.skip(f"needs {src}")
    head = tmp_path / name
    # the first lines and the footer (PrusaSlicer writes its estimate at the end)
    raw = src.read_bytes().splitlines(keepends=True)
    head.write_bytes(b"".join(raw[:lines] + raw[-400:]))
    out, rep = tmp_path / "out.gcode", tmp_path / "r.json"
    r = subprocess.run([sys.executable, "-m", "gcode_feedopt", str(head), "-o", str(out),
                        "--machine", "ender3pro", "--method", method, "--allow-slower",
                        "--report", str(rep)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    report = json.loads(rep.read_text())
    t_out = report["output_time_s"]
    assert abs(t_out - report["plan_time_s"]) > 1e-3  # else this test proves nothing
    text = out.read_bytes().decode()
    m = re.search(r"^;TIME:(\d+)", text, re.M)
    if m:
        assert int(m.group(1)) == int(round(t_out))
        elapsed = [float(v) for v in re.findall(r"^;TIME_ELAPSED:([\d.]+)", text, re.M)]
        assert elapsed and max(elapsed) <= t_out + 1e-6  # 5000 lines span two layer ends
    est = re.findall(r"^; estimated printing time \(normal mode\) = (.*)$", text, re.M)
    if est:
        assert est[0].strip() == format_duration(t_out)
    assert m or est
    # and the summary on stderr says the same, at the same rounding: `.. -> 6m00s (..`
    from gcode_feedopt.report import hms
    said = re.search(r"-> (\S+) \(", r.stderr)
    assert said, r.stderr
    assert said.group(1) == hms(t_out)
    if m:
        assert said.group(1) == hms(int(m.group(1)))
