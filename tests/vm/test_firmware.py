"""Firmware planner models against hand-computed trapezoids and junction speeds."""

import dataclasses
import math

import numpy as np
import pytest

from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.profile import load_profile
from gcode_feedopt.firmware import Replay, build_blocks, firmware_junctions
from gcode_feedopt.vm.firmware import estimate_time_s, execute

# accel 3000, JD 0.013, max feed x/y 500: the firmware's own junction settings, not the plan's
# from the hardware's speed step (tests/firmware/test_junctions.py)
MARLIN = firmware_junctions(load_profile("ender3pro"))
KLIPPER = dataclasses.replace(MARLIN, firmware=dataclasses.replace(
    MARLIN.firmware, flavour="klipper", g91_relative_e=False, square_corner_velocity_mm_s=5.0,
    minimum_cruise_ratio=0.0))


def prog(text, flavour="marlin"):
    return read_program(text.encode(), "t", flavour=flavour)


def test_single_move_trapezoid():
    # 100 mm at F6000 (100 mm/s), a = 3000: t = L/v + v/a
    p = prog("G1 X0 Y0 F6000\nG1 X100 Y0\n")
    assert estimate_time_s(p, MARLIN) == pytest.approx(100 / 100 + 100 / 3000, rel=1e-12)
    # M204 in the file lowers it
    p = prog("M204 P500 T500\nG1 X0 Y0 F6000\nG1 X100 Y0\n")
    assert estimate_time_s(p, MARLIN) == pytest.approx(1.0 + 100 / 500, rel=1e-12)


def test_m203_caps_feed_and_m201_caps_accel():
    p = prog("M203 X50\nG1 X0 Y0 F6000\nG1 X100 Y0\n")
    assert estimate_time_s(p, MARLIN) == pytest.approx(100 / 50 + 50 / 3000, rel=1e-12)
    p = prog("M201 X1000\nG1 X0 Y0 F6000\nG1 X100 Y0\n")
    assert estimate_time_s(p, MARLIN) == pytest.approx(1.0 + 100 / 1000, rel=1e-12)


def test_junction_deviation_90_degrees():
    p = prog("G1 X0 Y0 F6000\nG1 X50 Y0\nG1 X50 Y50\n")
    b = build_blocks(Replay(p, MARLIN))
    sd = math.sin(math.pi / 4)
    vj = math.sqrt(3000 * 0.013 * sd / (1 - sd))
    # two blocks, 50 mm each, rest -> 100 mm/s -> vj -> 100 -> rest
    t_one = lambda v0, v1: (50 - (100 ** 2 - v0 ** 2) / 6000 - (100 ** 2 - v1 ** 2) / 6000) / 100 \
        + (100 - v0) / 3000 + (100 - v1) / 3000
    assert estimate_time_s(p, MARLIN) == pytest.approx(t_one(0, vj) + t_one(vj, 0), rel=1e-9)
    assert b.turn_cos[0] == pytest.approx(0.0)


def test_classic_jerk_from_the_file():
    p = prog("M205 X8 Y8\nG1 X0 Y0 F6000\nG1 X50 Y0\nG1 X50 Y50\n")
    b = build_blocks(Replay(p, MARLIN))
    # 90° corner: each axis changes by v, so v = 8 mm/s
    assert b.jerk_v[0] == pytest.approx(8.0)


def test_klipper_square_corner_velocity():
    # Klipper: a 90° corner runs at square_corner_velocity (when not limited by centripetal)
    p = prog("G1 X0 Y0 F6000\nG1 X50 Y0\nG1 X50 Y50\n", "klipper")
    tr = execute(p, KLIPPER)
    v = np.linalg.norm(np.diff(tr.pos_mm[:, :2], axis=0), axis=1) / tr.ts_s
    at_corner = np.argmin(np.linalg.norm(tr.pos_mm[:-1, :2] - [50, 0], axis=1))
    assert v[at_corner - 1:at_corner + 2].min() == pytest.approx(5.0, abs=3000 * 0.002)


def test_klipper_set_velocity_limit_in_file():
    p = prog("SET_VELOCITY_LIMIT VELOCITY=50 ACCEL=1000\nG1 X0 Y0 F6000\nG1 X100 Y0\n", "klipper")
    assert estimate_time_s(p, KLIPPER) == pytest.approx(100 / 50 + 50 / 1000, rel=1e-12)


def test_klipper_minimum_cruise_ratio_slows_short_moves():
    k2 = dataclasses.replace(KLIPPER, firmware=dataclasses.replace(KLIPPER.firmware,
                                                                   minimum_cruise_ratio=0.5))
    p = prog("G1 X0 Y0 F6000\nG1 X5 Y0\n", "klipper")
    assert estimate_time_s(p, k2) > estimate_time_s(p, KLIPPER)


def test_execute_ends_at_last_point_with_e_and_stops():
    p = prog("M82\nG1 X0 Y0 F3000\nG1 X20 Y0 E1\nG1 E0.5 F1800\nG4 P200\nG2 X40 Y0 I10 J0 E2 F1200\n")
    tr = execute(p, MARLIN)
    np.testing.assert_allclose(tr.pos_mm[-1], [40, 0, 0], atol=1e-9)
    assert tr.e_mm[-1] == pytest.approx(2.0)
    assert tr.duration_s >= estimate_time_s(p, MARLIN) - 1e-9
    # the dwell: the machine stands still for 0.2 s somewhere
    still = np.all(np.abs(np.diff(tr.pos_mm, axis=0)) < 1e-12, axis=1) & (np.diff(tr.e_mm) == 0)
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], still.astype(int), [0]]))))[::2]
    assert runs.max() * tr.ts_s >= 0.2 - 2 * tr.ts_s
    # the samples know their moves: in the extruding line and arc, not in the retraction,
    # the dwell or before the first move
    ext = tr.in_extrusion
    assert ext.shape == (tr.n_samples,)
    assert ext[0] == (tr.pos_mm[1, 0] > 0)
    mid_line = np.flatnonzero((tr.pos_mm[:, 0] > 1) & (tr.pos_mm[:, 0] < 19))
    assert ext[mid_line].all()
    retracting = np.flatnonzero(np.diff(tr.e_mm) < 0)
    assert retracting.size and not ext[retracting[1:]].any()  # the retraction at X20
    assert ext[tr.pos_mm[:, 0] > 20.5].all()
    # arcs are split into chords on the circle
    assert np.all(np.abs(np.hypot(tr.pos_mm[tr.pos_mm[:, 0] > 20.5, 0] - 30,
                                  tr.pos_mm[tr.pos_mm[:, 0] > 20.5, 1]) - 10) < 0.02)


# Klipper's rules as klippy (84104bb) applies them; the same rules time real files within
# microseconds of real Klipper (tests/vm/test_klipper_referee.py)
K0 = dataclasses.replace(KLIPPER, firmware=dataclasses.replace(
    KLIPPER.firmware, max_feed_mm_s={"x": 300.0, "y": 300.0, "z": 5.0, "e": 25.0},
    max_accel_mm_s2={"x": 3000.0, "y": 3000.0, "z": 100.0, "e": 3000.0}))


def one_move_s(L, v, a):
    """Rest to rest over L at cruise v (reached) and accel a."""
    return L / v + v / a


@pytest.mark.parametrize("line, accel", [
    ("M204 S1000", 1000.0),
    ("M204 P1000 T2000", 1000.0),       # the smaller of P and T
    ("M204 P800", 3000.0),              # P alone: refused by Klipper, nothing changes
    ("M204 T800", 3000.0),
    ("M204 P1000 R500 T2000", 1000.0),  # R is no Klipper parameter
    ("M201 X500 Y500", 3000.0),         # M201 / M203 are no Klipper commands
    ("M203 X20 Y20", 3000.0),
])
def test_klipper_m204_and_what_klipper_ignores(line, accel):
    p = prog(f"{line}\nG1 X0 Y0 F6000\nG1 X100 Y0\n", "klipper")
    assert estimate_time_s(p, K0) == pytest.approx(one_move_s(100, 100, accel), rel=1e-12)
    # the Marlin model honours them (a travel: M204 T)
    if line.startswith(("M201", "M203", "M204 T800")):
        assert estimate_time_s(prog(f"{line}\nG1 X0 Y0 F6000\nG1 X100 Y0\n"), MARLIN) \
            != pytest.approx(one_move_s(100, 100, 3000.0), rel=1e-9)


def test_klipper_z_limits_scale_with_the_move():
    # a Z-only move: max_z_velocity 5, max_z_accel 100
    p = prog("G1 Z0 F600\nG1 Z2\n", "klipper")
    assert estimate_time_s(p, K0) == pytest.approx(one_move_s(2, 5, 100), rel=1e-12)
    # X 3, Z 4 (L = 5): limits × L/|dZ| = 1.25, so 6.25 mm/s and 125 mm/s²
    p = prog("G1 X0 Z0 F6000\nG1 X3 Z4\n", "klipper")
    assert estimate_time_s(p, K0) == pytest.approx(one_move_s(5, 6.25, 125), rel=1e-12)


def test_klipper_extrude_only_limits_on_retracting_moves():
    # retracting while travelling: extrude-only limits × L/|dE|; 10 mm with E-5: 50 mm/s,
    # 6000 mm/s² (above max_accel: 3000)
    p = prog("M83\nG1 X0 Y0 F6000\nG1 X10 E-5\n", "klipper")
    assert estimate_time_s(p, K0) == pytest.approx(one_move_s(10, 50, 3000), rel=1e-12)
    # extruding with XY: no extruder limit; M221 scales E (E-only move: 4 × 0.5 mm at 25 mm/s)
    p = prog("M83\nG1 X0 Y0 F6000\nG1 X10 E5\nM221 S50\nG1 E4 F6000\n", "klipper")
    assert estimate_time_s(p, K0) == pytest.approx(one_move_s(10, 100, 3000)
                                                   + one_move_s(2, 25, 3000), rel=1e-12)


def test_klipper_extruder_corner_velocity():
    # straight on from extruding (dE/L = 0.05) into travel: the extruder's speed may jump by
    # instantaneous_corner_velocity (1 mm/s), so the junction runs at 1 / 0.05 = 20 mm/s
    p = prog("M83\nG1 X0 Y0 F6000\nG1 X50 E2.5\nG1 X100\n", "klipper")
    b = build_blocks(Replay(p, K0))
    np.testing.assert_allclose(b.e_ratio, [0.05, 0.0])
    vj = 20.0
    half = ((50 - (100 ** 2 - vj ** 2) / 6000 - 100 ** 2 / 6000) / 100
            + (100 - vj) / 3000 + 100 / 3000)
    assert estimate_time_s(p, K0) == pytest.approx(2 * half, rel=1e-12)
    icv2 = dataclasses.replace(K0, firmware=dataclasses.replace(
        K0.firmware, instantaneous_corner_velocity_mm_s=2.0))
    assert estimate_time_s(p, icv2) < estimate_time_s(p, K0)


def test_klipper_minimum_cruise_ratio_carries_over_runs_of_short_moves():
    # ten collinear 1 mm moves run as one 10 mm move: minimum_cruise_ratio 0.5 gives the whole
    # run one peak (the pseudo-accel's 1500 mm/s² over 10 mm), not each move its own
    mcr = dataclasses.replace(K0, firmware=dataclasses.replace(K0.firmware,
                                                               minimum_cruise_ratio=0.5))
    run = "".join(f"G1 X{i}\n" for i in range(1, 11))
    p_run = prog("G1 X0 Y0 F18000\n" + run, "klipper")
    p_one = prog("G1 X0 Y0 F18000\nG1 X10\n", "klipper")
    vc = math.sqrt(1500 * 10)
    t = 2 * vc / 3000 + (10 - vc * vc / 3000) / vc
    assert estimate_time_s(p_one, mcr) == pytest.approx(t, rel=1e-12)
    assert estimate_time_s(p_run, mcr) == pytest.approx(t, rel=1e-9)
    # without the ratio: the triangle at 3000 mm/s²
    assert estimate_time_s(p_run, K0) == pytest.approx(2 * math.sqrt(10 / 3000), rel=1e-9)
