"""A planned segment written as one line at the plan's own peak speed (pieces.plan_peaks): the
firmware model then runs the written file as planned, where lines at the sampled speeds (the
fastest sample interval's mean, split into a staircase where a short segment starts near rest)
run several percent slower. And E-only moves last in the plan what the firmware gives them."""

import dataclasses

import numpy as np
import pytest

from gcode_feedopt import firmware
from gcode_feedopt.gcode.path import build_path
from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.gcode.verify import verify
from gcode_feedopt.gcode.writer import write
from gcode_feedopt.pipeline import path_for
from gcode_feedopt.plan.kinematic import plan_kinematic, writer_accel
from gcode_feedopt.profile import load_profile
from gcode_feedopt.vm.firmware import estimate_time_s

MARLIN = load_profile("ender3pro")
KLIPPER = dataclasses.replace(MARLIN, firmware=dataclasses.replace(
    MARLIN.firmware, flavour="klipper", g91_relative_e=False, square_corner_velocity_mm_s=5.0,
    minimum_cruise_ratio=0.0))


def zigzag(jerk: bool = False) -> bytes:
    """300 short extrusions (0.15–0.65 mm) with reversals and random turns: infill-like,
    many segments too short to reach their feed and starting near rest."""
    lines = ["G90", "M82", "G92 E0"] + (["M205 X8 Y8"] if jerk else []) + ["G1 X10 Y10 F6000"]
    x, y, e = 10.0, 10.0, 0.0
    rng = np.random.default_rng(1)
    for k in range(300):
        length = 0.15 + 0.5 * rng.random()
        ang = rng.uniform(0, 2 * np.pi) if k % 7 == 0 else (np.pi if k % 2 else 0.3)
        x += length * np.cos(ang + k * 0.05)
        y += length * np.sin(ang + k * 0.05)
        e += 0.03 * length
        lines.append(f"G1 X{x:.3f} Y{y:.3f} E{e:.5f} F3000")
    return ("\n".join(lines) + "\n").encode()


def written_time(data: bytes, profile, keep_peaks: bool):
    fw = profile.firmware
    prog = read_program(data, "z.gcode", flavour=fw.flavour, g91_relative_e=fw.g91_relative_e)
    path = build_path(prog)
    limits = firmware.move_limits(prog, profile)
    sched = plan_kinematic(path, profile, fw_limits=limits)
    if not keep_peaks:
        sched = dataclasses.replace(sched, segment_plan=None)
    res = write(prog, path, sched, profile, accel_mm_s2=writer_accel(path, profile, limits))
    out = verify(prog, res, flavour=fw.flavour, g91_relative_e=fw.g91_relative_e)
    return sched.duration_s, estimate_time_s(out, profile), res, path


@pytest.mark.parametrize("profile", [MARLIN, KLIPPER], ids=["marlin-jd", "klipper"])
def test_one_line_at_the_plans_peak_runs_as_planned(profile):
    plan_s, fw_s, res, path = written_time(zigzag(), profile, keep_peaks=True)
    assert fw_s == pytest.approx(plan_s, rel=5e-4)
    assert res.sub_moves == path.n_segments  # one line per segment
    # from the samples alone: a staircase of lines, measurably slower
    _, fw_sampled, res_sampled, _ = written_time(zigzag(), profile, keep_peaks=False)
    assert fw_sampled > plan_s * 1.02
    assert res_sampled.sub_moves > res.sub_moves


def test_classic_jerk_segments_are_written_at_the_plans_cap():
    """Classic jerk sets a junction from the nominal speeds of both moves: F is part of the
    junction rule, so a segment with such a junction is one line at the plan's feed cap (the
    nominal speed its junctions were planned with), not at its peak, and the firmware runs it
    as planned; from the samples alone it was a staircase of lines (the PrusaSlicer MINI
    Benchy ran 1.0 % slower than planned that way)."""
    plan_s, fw_s, res, path = written_time(zigzag(jerk=True), MARLIN, keep_peaks=True)
    assert fw_s == pytest.approx(plan_s, rel=5e-4)
    assert res.sub_moves == path.n_segments
    _, fw_sampled, res_sampled, _ = written_time(zigzag(jerk=True), MARLIN, keep_peaks=False)
    assert fw_sampled > plan_s * 1.01
    assert res_sampled.sub_moves > res.sub_moves


def test_e_only_moves_last_what_the_firmware_gives_them():
    """The retract acceleration (M204 R) and extruder feed cap (M203 E) in the file set the
    plan's standstill for every retraction and prime, as they set the firmware's."""
    lines = ["G90", "M82", "G92 E0", "M204 R500", "M203 E30", "G1 X10 Y10 F6000"]
    e = 0.0
    for k in range(6):
        e += 1.0
        lines.append(f"G1 X{20 + 10 * k} Y10 E{e:.4f} F3000")
        lines += [f"G1 E{e - 4:.4f} F2700", f"G1 X{20 + 10 * k} Y20 F6000", f"G1 E{e:.4f} F2700"]
        if k == 2:
            lines.append("M204 R2000")
    fw = MARLIN.firmware
    prog = read_program(("\n".join(lines) + "\n").encode(), "r.gcode", flavour=fw.flavour,
                        g91_relative_e=fw.g91_relative_e)
    path = path_for(prog, MARLIN)
    blocks = firmware.build_blocks(firmware.Replay(prog, MARLIN))
    tr = blocks.plan()
    e_only = np.all(blocks.end_mm == blocks.start_mm, axis=1)
    assert e_only.sum() == 12
    assert path.dwell_after_s.sum() + path.dwell_before_s == pytest.approx(
        tr.motion_s[e_only].sum(), rel=1e-12)
    # the profile's file-wide extruder limits (what the plan used before) miss by 70 ms here
    flat = build_path(prog, e_feed_cap_mm_s=fw.max_feed_mm_s["e"],
                      e_accel_mm_s2=fw.max_accel_mm_s2["e"])
    assert abs(flat.dwell_after_s.sum() - path.dwell_after_s.sum()) > 0.05
