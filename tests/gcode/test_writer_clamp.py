"""Where the file lets the firmware accelerate harder than the plan (``--amax``, a profile's
lower axis limits than the file's ``M201``), the writer sets the plan's limits (Marlin
``M201 X Y Z``, Klipper ``SET_VELOCITY_LIMIT ACCEL``) so the written file runs as planned, and
gives the file's own values back after the last move."""

import dataclasses

import numpy as np
import pytest

from gcode_feedopt import firmware
from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.pipeline import Options, optimize_file
from gcode_feedopt.profile import load_profile

# the printer runs the profile's limits as its configuration (no configured_* lines to set
# and restore them around the file, no hardware junction limit above the firmware's:
# tests/gcode/test_writer_configured.py)
MARLIN = dataclasses.replace(load_profile("ender3pro"), firmware=dataclasses.replace(
    load_profile("ender3pro").firmware, configured_accel_mm_s2=None,
    configured_max_accel_mm_s2=None), limits=dataclasses.replace(
    load_profile("ender3pro").limits, axis_jerk_mm_s=None))  # X/Y 3000, Z 100 mm/s²
KLIPPER = dataclasses.replace(MARLIN, firmware=dataclasses.replace(
    MARLIN.firmware, flavour="klipper", g91_relative_e=False, square_corner_velocity_mm_s=5.0,
    minimum_cruise_ratio=0.0))


def part(head: list[str], mid: list[str] | None = None) -> bytes:
    """Two layers of a 20 mm square with diagonal infill, a Z hop between them."""
    lines = ["G90", "M82", "G92 E0", *head, "G1 Z0.2 F600", "G1 X10 Y10 F9000"]
    e = 0.0
    rng = np.random.default_rng(3)
    for layer in range(2):
        if layer == 1:
            lines += [*(mid or []), "G1 Z0.6 F720", "G1 Z0.4 F720"]
        for k in range(40):
            x, y = 10 + 20 * rng.random(), 10 + 20 * rng.random()
            e += 0.5
            lines.append(f"G1 X{x:.3f} Y{y:.3f} E{e:.4f} F{3000 + 60 * k}")
    lines.append("M84")
    return ("\n".join(lines) + "\n").encode()


def run(tmp_path, data: bytes, profile, **opts):
    src = tmp_path / "in.gcode"
    src.write_bytes(data)
    out = tmp_path / "out.gcode"
    # allow_slower: a lower --amax makes the output slower than the file, which is the point
    rep = optimize_file(src, out, profile, Options(method="kinematic", allow_slower=True, **opts))
    return rep, out.read_bytes()


def accel_lines(data: bytes, prefix: bytes) -> list[tuple[int, bytes]]:
    return [(k, ln) for k, ln in enumerate(data.splitlines()) if ln.startswith(prefix)]


def test_amax_below_the_firmware_is_told_to_the_firmware(tmp_path):
    rep_full, _ = run(tmp_path, part([]), MARLIN)
    rep, data = run(tmp_path, part([]), MARLIN, amax_mm_s2=1000.0)
    assert rep.plan_time_s > rep_full.plan_time_s * 1.02  # the lower limit costs time
    # the firmware runs what we planned (it ran 3000 mm/s² before: several % faster)
    assert rep.output_time_s == pytest.approx(rep.plan_time_s, rel=1e-3)
    lines = accel_lines(data, b"M201 ")
    assert [ln for _, ln in lines] == [b"M201 X1000 Y1000 Z100", b"M201 X3000 Y3000 Z100"]
    text = data.splitlines()
    first_move = next(k for k, ln in enumerate(text) if ln.startswith(b"G1 "))
    last_move = max(k for k, ln in enumerate(text) if ln.startswith(b"G1 "))
    assert lines[0][0] < first_move and lines[1][0] == last_move + 1
    # the firmware's settings at the end are the file's (profile's) own
    out = read_program(data, "o")
    snaps = firmware.Replay(out, MARLIN).snaps
    assert snaps[-1].max_accel == MARLIN.firmware.max_accel_mm_s2


def test_file_setting_higher_limits_is_followed_by_ours(tmp_path):
    """The file raises M201 (a Prusa start block: Z400) before its moves and again mid-file:
    our line follows each, and the Z hop runs at the profile's Z limit as planned."""
    head = ["M201 X2500 Y2500 Z400 E5000"]
    rep, data = run(tmp_path, part(head, mid=["M201 X2500 Y2500 Z400 E5000"]), MARLIN,
                    accel="file")
    lines = [ln for _, ln in accel_lines(data, b"M201 ")]
    assert lines == [b"M201 X2500 Y2500 Z400 E5000", b"M201 X2500 Y2500 Z100",
                     b"M201 X2500 Y2500 Z400 E5000", b"M201 X2500 Y2500 Z100",
                     b"M201 X2500 Y2500 Z400"]
    assert rep.output_time_s == pytest.approx(rep.plan_time_s, rel=1e-3)
    # --accel plan (the default): the file's X/Y 2500 give way to the plan's 3000 (our line
    # after each of its M201), the clamp then holds Z; the file's own X/Y back at the end
    rep, data = run(tmp_path, part(head, mid=["M201 X2500 Y2500 Z400 E5000"]), MARLIN)
    lines = [ln.split(b" ;")[0] for _, ln in accel_lines(data, b"M201 ")]
    assert lines == [b"M201 X2500 Y2500 Z400 E5000", b"M201 X3000 Y3000", b"M201 X3000 Y3000 Z100",
                     b"M201 X2500 Y2500 Z400 E5000", b"M201 X3000 Y3000", b"M201 X3000 Y3000 Z100",
                     b"M201 X3000 Y3000 Z400", b"M201 X2500 Y2500"]
    assert rep.output_time_s == pytest.approx(rep.plan_time_s, rel=1e-3)


def test_no_lines_when_the_file_is_within_the_plan(tmp_path):
    data = part(["M201 X1500 Y1500 Z50"])
    prog = read_program(data, "p")
    axis_a = {"x": 3000.0, "y": 3000.0, "z": 100.0}
    assert firmware.accel_clamp(prog, MARLIN, axis_a) is None
    rep, out = run(tmp_path, data, MARLIN, accel="file")
    assert [ln for _, ln in accel_lines(out, b"M201 ")] == [b"M201 X1500 Y1500 Z50"]
    assert rep.extra["accel_lines"] == 0
    # --accel plan: no clamp either, but the file's X/Y 1500 give way to the plan's 3000
    rep, out = run(tmp_path, data, MARLIN)
    assert [ln.split(b" ;")[0] for _, ln in accel_lines(out, b"M201 ")] == [
        b"M201 X1500 Y1500 Z50", b"M201 X3000 Y3000", b"M201 X1500 Y1500"]
    assert rep.extra["accel_lines"] == rep.extra["accel_override_lines"] == 2


def test_klipper_accel_is_clamped(tmp_path):
    head = ["SET_VELOCITY_LIMIT ACCEL=5000"]
    rep, data = run(tmp_path, part(head), KLIPPER, amax_mm_s2=2000.0)
    lines = [ln for _, ln in accel_lines(data, b"SET_VELOCITY_LIMIT")]
    assert lines == [b"SET_VELOCITY_LIMIT ACCEL=5000", b"SET_VELOCITY_LIMIT ACCEL=2000",
                     b"SET_VELOCITY_LIMIT ACCEL=5000"]
    assert rep.output_time_s == pytest.approx(rep.plan_time_s, rel=1e-3)


@pytest.mark.parametrize("mid, after", [
    (["M204 P800"], []),                                   # refused by Klipper: no new line
    (["M204 S4000"], [b"SET_VELOCITY_LIMIT ACCEL=2000"]),  # sets 4000: ours follows it
])
def test_klipper_clamp_follows_only_lines_klipper_accepts(tmp_path, mid, after):
    head = ["SET_VELOCITY_LIMIT ACCEL=5000"]
    rep, data = run(tmp_path, part(head, mid=mid), KLIPPER, amax_mm_s2=2000.0)
    lines = [ln for _, ln in accel_lines(data, b"SET_VELOCITY_LIMIT")]
    restore = b"SET_VELOCITY_LIMIT ACCEL=" + (b"4000" if after else b"5000")
    assert lines == [b"SET_VELOCITY_LIMIT ACCEL=5000", b"SET_VELOCITY_LIMIT ACCEL=2000",
                     *after, restore]
    assert rep.output_time_s == pytest.approx(rep.plan_time_s, rel=1e-3)
