"""Slowed stretches of a slow-down plan: the writer tells the firmware their acceleration and
junction rule, restores the settings after them, and the firmware model runs the written file
as planned."""

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from gcode_feedopt import firmware
from gcode_feedopt.gcode.path import build_path
from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.gcode.schedule import Schedule, SlowdownCells
from gcode_feedopt.gcode.verify import verify
from gcode_feedopt.gcode.writer import T_ACCEL, T_ORIG, write
from gcode_feedopt.optimize.methods import _segment_plan
from gcode_feedopt.optimize.slowdown import _cell_peaks
from gcode_feedopt.optimize.slowdown.grid import PlanGrid
from gcode_feedopt.plan.kinematic import effective_limits, planner_limits, writer_accel
from gcode_feedopt.profile import load_profile
from gcode_feedopt.vm.firmware import estimate_time_s

# the printer runs the profile's limits as its configuration (no configured_* lines to set
# and restore them around the file, no hardware junction limit above the firmware's:
# tests/gcode/test_writer_configured.py, tests/gcode/test_writer_junctions.py)
MARLIN = dataclasses.replace(load_profile("ender3pro"), firmware=dataclasses.replace(
    load_profile("ender3pro").firmware, configured_accel_mm_s2=None,
    configured_max_accel_mm_s2=None), limits=dataclasses.replace(
    load_profile("ender3pro").limits, axis_jerk_mm_s=None))
KLIPPER = dataclasses.replace(MARLIN, firmware=dataclasses.replace(
    MARLIN.firmware, flavour="klipper", g91_relative_e=False, square_corner_velocity_mm_s=5.0,
    minimum_cruise_ratio=0.0))


def spiral(jerk: bool) -> bytes:
    lines = ["; a test part", "G90", "M82", "G92 E0"]
    if jerk:
        lines.append("M205 X8 Y8")
    lines.append("G1 X10 Y10 F6000")
    e = 0.0
    x, y = 10.0, 10.0
    for k in range(24):
        d = 40.0 - 1.5 * k
        dx, dy = [(d, 0), (0, d), (-d, 0), (0, -d)][k % 4]
        x, y = x + dx, y + dy
        e += 0.03 * abs(dx + dy)
        lines.append(f"G1 X{x:.3f} Y{y:.3f} E{e:.5f} F4200")
        if k == 9:
            lines += [";TYPE:travel", "M106 S128", f"G1 E{e - 1:.5f} F2700", f"G1 E{e:.5f} F2700"]
        if k % 5 == 2:
            lines.append(";WIDTH:0.45")
    lines.append("; end of part")
    return ("\n".join(lines) + "\n").encode()


def slowed_plan(prog, path, profile, scale_of, peaks=True):
    """A slow-down plan of ``path``: the firmware's own plan with every grid cell scaled by
    ``scale_of(cell_index, n_cells)`` (PlanGrid, as optimize.slowdown plans)."""
    vmax, axis_v, axis_a = effective_limits(profile, None, None)
    fw_limits = firmware.move_limits(prog, profile)
    limits = planner_limits(path, vmax_mm_s=vmax, axis_vmax_mm_s=axis_v, axis_amax_mm_s2=axis_a,
                            firmware=profile.firmware, fw_limits=fw_limits)
    grid = PlanGrid(path, limits, 1.5, profile.ts_s)
    scale = np.array([scale_of(c, grid.n_cells) for c in range(grid.n_cells)], float)
    scale[grid.fixed] = 1.0
    ss, _, _, v0 = grid.plan(scale, np.arange(grid.n_pieces))
    parts = [np.zeros(grid.lead_hold + 1)]
    for p, sp in enumerate(ss):
        parts += [sp, np.full(grid.piece_hold[p], sp[-1])]
    s = np.concatenate(parts)
    cells = SlowdownCells(s0_mm=grid.s0_mm, parent=grid.parent, scale=scale,
                          accel_mm_s2=grid.accel_mm_s2 * scale * scale,
                          vcap_mm_s=grid.vcap_mm_s * scale)
    sp = None
    if peaks:  # what plan_slowdown and plan_offline hand the writer
        cells = dataclasses.replace(
            cells, vpeak_mm_s=_cell_peaks(grid, SimpleNamespace(v0=v0, scale=scale)),
            jerk_junction=grid.jerk_junction)
        sp = _segment_plan(cells, path.n_segments)
    return (Schedule(ts_s=profile.ts_s, s_mm=s, method="pidd", segment_plan=sp), cells,
            fw_limits)


def write_both(data, profile, scale_of, peaks=True):
    fw = profile.firmware
    prog = read_program(data, "t.gcode", flavour=fw.flavour, g91_relative_e=fw.g91_relative_e)
    path = build_path(prog)
    sched, cells, fw_limits = slowed_plan(prog, path, profile, scale_of, peaks)
    acc = writer_accel(path, profile, fw_limits)
    told = write(prog, path, sched, profile, accel_mm_s2=acc, cells=cells,
                 settings=firmware.accel_settings(prog, profile))
    plain = write(prog, path, sched, profile, accel_mm_s2=acc)
    outs = [verify(prog, r, flavour=fw.flavour, g91_relative_e=fw.g91_relative_e)
            for r in (told, plain)]
    return prog, sched, told, plain, outs


def wavy(c, n):
    """Slowed stretches of different depth, full speed between them."""
    return 1.0 if (c // 3) % 3 == 0 else 0.45 + 0.2 * ((c // 3) % 3)


@pytest.mark.parametrize("profile,jerk", [(MARLIN, True), (MARLIN, False), (KLIPPER, False)],
                         ids=["marlin-jerk", "marlin-jd", "klipper"])
def test_firmware_runs_a_slowed_plan_as_planned(profile, jerk):
    prog, sched, told, plain, (out_told, out_plain) = write_both(spiral(jerk), profile, wavy)
    t_plan = sched.duration_s
    t_told = estimate_time_s(out_told, profile)
    t_plain = estimate_time_s(out_plain, profile)
    # told the cell accelerations, the firmware's plan is ours (to the writer's 5 % speed band
    # and Ts sampling); a staircase of F values at full acceleration runs measurably slower
    assert t_told == pytest.approx(t_plan, rel=0.002)
    assert abs(t_plain - t_plan) > 2 * abs(t_told - t_plan)
    assert told.accel_lines > 0
    # one line per cell run (no staircase): fewer motion lines than without
    assert told.sub_moves < plain.sub_moves
    text = told.data.decode()
    if profile.firmware.flavour == "klipper":
        assert "SET_VELOCITY_LIMIT ACCEL=" in text and "M204" not in text
    else:
        assert "M204 P" in text and "SET_VELOCITY_LIMIT" not in text
        assert ("M205 X" in text) == jerk


@pytest.mark.parametrize("profile,jerk", [(MARLIN, True), (KLIPPER, False)],
                         ids=["marlin-jerk", "klipper"])
def test_settings_restored_before_every_untouched_line_and_at_the_end(profile, jerk):
    prog, sched, told, plain, (out, _) = write_both(spiral(jerk), profile, wavy)
    klipper = profile.firmware.flavour == "klipper"
    before = firmware.accel_settings(prog, profile)
    after = firmware.accel_settings(out, profile)
    lines = told.data.split(b"\n")
    # every untouched motion line (the E-only retraction) runs with the file's own settings
    n_checked = 0
    for j, mv in enumerate(out.moves):
        tag, i = told.tags[mv.line_no]
        if tag != T_ORIG:
            continue
        orig = next(k for k, m in enumerate(prog.moves) if m.line_no == i)
        for f in ("accel_print_mm_s2", "accel_travel_mm_s2", "scv_mm_s"):
            assert getattr(after, f)[j] == getattr(before, f)[orig]
        np.testing.assert_array_equal(after.jerk_xy_mm_s[j], before.jerk_xy_mm_s[orig])
        n_checked += 1
    assert n_checked == 2
    # no setting line of ours stands right before a non-comment line we did not re-time
    for k, (tag, i) in enumerate(told.tags[:-1]):
        if tag == T_ORIG and not lines[k].startswith(b";"):
            prev = told.tags[k - 1][0]
            if prev == T_ACCEL:
                # only the restore may precede it: the settings in force are the file's
                assert lines[k - 1].startswith((b"M204", b"M205", b"SET_VELOCITY_LIMIT"))
    # the last slowed cell ends the part: the file ends with the settings it started with
    snaps_in = firmware.Replay(prog, profile).snaps
    snaps_out = firmware.Replay(out, profile).snaps
    a, b = snaps_in[-1], snaps_out[-1]
    assert (a.accel_print, a.accel_travel, a.scv, a.jerk) == (b.accel_print, b.accel_travel,
                                                               b.scv, b.jerk)
    assert lines[-2] == b"; end of part"  # the restore goes before the trailing comment


def test_no_setting_lines_where_nothing_is_slowed():
    prog, sched, told, plain, _ = write_both(spiral(True), MARLIN, lambda c, n: 1.0)
    assert told.accel_lines == 0
    assert told.data == plain.data


@pytest.mark.parametrize("profile", [MARLIN, KLIPPER], ids=["marlin", "klipper"])
def test_a_stretch_slowed_below_one_mm_s2_is_told_its_acceleration(profile):
    """A move sliced at 100 mm/s² slowed to a twentieth of its speed plans 0.25 mm/s²: the
    writer rounded the stretch's acceleration down to whole units and wrote ``M204 P0``
    (``ACCEL=0``), which the output's own check refused (seen planning a foreign servo's
    butterfly at η 0.99: "M204 P0 is outside 0.001 to 1e+07"). Below 1 mm/s² it keeps 0.001,
    rounded down, the output reads back (``write_both`` verifies it) and both firmware models
    run it as planned (Marlin's ran it 25 % faster: the reader lost ``M204 P0.25 T0.25``,
    whose T pygcode reads as an integer)."""
    data = spiral(False).replace(b"G92 E0\n", b"G92 E0\nM204 P100 T100\n"
                                 if profile.firmware.flavour != "klipper" else
                                 b"G92 E0\nSET_VELOCITY_LIMIT ACCEL=100\n")
    prog, sched, told, plain, (out, _) = write_both(data, profile,
                                                    lambda c, n: 0.05 if c % 6 < 3 else 1.0)
    text = told.data.decode()
    key = "SET_VELOCITY_LIMIT ACCEL=" if profile.firmware.flavour == "klipper" else "M204 P"
    told_acc = [float(ln.split(key, 1)[1].split()[0]) for ln in text.splitlines() if key in ln]
    assert min(told_acc) == pytest.approx(0.25, abs=1e-3)
    assert len(out.moves) == len(prog.moves) + told.sub_moves - told.moves_changed
    assert estimate_time_s(out, profile) == pytest.approx(sched.duration_s, rel=0.002)
