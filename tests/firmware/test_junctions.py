"""The plan's junctions from the hardware's speed step (issue 20 point 2, junctions).

A profile states ``limits.axis_jerk_mm_s`` J: the largest instantaneous change of an axis's
speed its motors take. ``firmware.plan_junction`` turns it into each firmware's junction
setting; ``--accel plan`` raises the file's lower ones and the writer sets the plan's before the
first move where the firmware is configured lower. Checked here against brute force over turns
(the speed step of the firmware's own junction rule never exceeds J, and reaches it), against
the lines a file gets, and against the profile's reader.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from gcode_feedopt import firmware
from gcode_feedopt.errors import ProfileError
from gcode_feedopt.firmware.klipper import klipper_junction_v2
from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.plan.trapezoid import junction_speeds
from gcode_feedopt.profile import load_profile, parse_profile
from gcode_feedopt.profile.io import profile_to_dict

SHIPPED = load_profile("ender3pro")


def with_jerk(profile, jerk, flavour=None):
    lim = dataclasses.replace(profile.limits, axis_jerk_mm_s=jerk)
    fw = profile.firmware if flavour is None else dataclasses.replace(
        profile.firmware, flavour=flavour, g91_relative_e=False)
    return dataclasses.replace(profile, limits=lim, firmware=fw)


def largest_axis_step(v: np.ndarray, phi: np.ndarray, heading: np.ndarray) -> float:
    """The largest change of one axis's speed over junctions at speed ``v`` turning by
    ``phi`` from direction ``heading``."""
    u0 = np.stack([np.cos(heading), np.sin(heading)], 1)
    u1 = np.stack([np.cos(heading + phi), np.sin(heading + phi)], 1)
    return float(np.max(np.abs(v[:, None] * (u1 - u0))))


#: turns from 0.2° (Marlin counts a junction within 0.08° of straight as straight on: the
#: feed cap alone limits it) to a near reversal
TURNS = np.linspace(3.5e-3, math.pi - 1e-3, 4001)
HEADINGS = np.linspace(0.0, math.pi / 2, 4001)


@pytest.mark.parametrize("jerk, accel", [(20.0, 3000.0), (10.0, 500.0), (35.0, 10000.0)])
def test_the_marlin_deviation_keeps_every_axis_step_within_the_hardwares(jerk, accel):
    prof = with_jerk(dataclasses.replace(SHIPPED, firmware=dataclasses.replace(
        SHIPPED.firmware, accel_mm_s2=accel, travel_accel_mm_s2=accel, junction_deviation_mm=0.0)),
        {"x": jerk, "y": jerk + 5.0})
    prof = dataclasses.replace(prof, limits=dataclasses.replace(prof.limits, amax_mm_s2=accel))
    jd = firmware.plan_junction(prof)["jd"]
    assert jd == math.floor(jerk * jerk / (8 * accel) * 1000) / 1000  # the smaller axis's J
    n = TURNS.size
    v = junction_speeds(np.cos(TURNS), np.full(n + 1, accel), jd, np.full(n + 1, np.inf),
                        np.zeros(n + 1, bool))[1:n + 1]
    step = largest_axis_step(v, TURNS, HEADINGS)
    # within J, and close to it (the bound √(8aδ) is reached at shallow turns; δ is rounded
    # down to 0.001 mm)
    assert step <= jerk
    assert step >= 0.9 * jerk * math.sqrt(jd / (jerk * jerk / (8 * accel)))


@pytest.mark.parametrize("jerk", [20.0, 8.0])
def test_the_klipper_square_corner_velocity_keeps_every_axis_step_within(jerk):
    prof = with_jerk(dataclasses.replace(SHIPPED, firmware=dataclasses.replace(
        SHIPPED.firmware, square_corner_velocity_mm_s=0.0)), {"x": jerk, "y": jerk}, "klipper")
    scv = firmware.plan_junction(prof)["scv"]
    assert scv == math.floor(jerk / math.sqrt(8 * (math.sqrt(2) - 1)) * 10) / 10
    for accel in (500.0, 5000.0):
        n = TURNS.size
        jd = np.full(n + 1, scv * scv * (math.sqrt(2) - 1) / accel)
        v2 = klipper_junction_v2(np.cos(TURNS), np.full(n + 1, accel), jd,
                                 np.full(n + 1, 1e9), np.full(n + 1, np.inf),
                                 np.zeros(n + 1, bool))
        step = largest_axis_step(np.sqrt(v2), TURNS, HEADINGS)
        assert 0.97 * jerk <= step <= jerk
        # a square corner runs at scv: each axis steps by scv there
        k = np.argmin(np.abs(TURNS - math.pi / 2))
        assert math.sqrt(v2[k]) == pytest.approx(scv, rel=1e-3)


def test_never_below_the_firmwares_own_and_nothing_without_a_hardware_limit():
    assert firmware.plan_junction(with_jerk(SHIPPED, None)) == {}
    # a J whose deviation is below the firmware's 0.013 mm keeps the firmware's
    pj = firmware.plan_junction(with_jerk(SHIPPED, {"x": 5.0, "y": 5.0}))
    assert pj["jd"] == 0.013 and pj["scv"] == 5.0 and pj["jerk_x"] == 5.0
    assert not firmware.raises_configured(dataclasses.replace(
        with_jerk(SHIPPED, {"x": 5.0, "y": 5.0}), firmware=dataclasses.replace(
            SHIPPED.firmware, configured_accel_mm_s2=None, configured_max_accel_mm_s2=None)))
    # the shipped Ender 3 Pro: 20 mm/s, 0.016 mm at 3000 mm/s²; as configured, the firmware's
    assert firmware.plan_junction(SHIPPED)["jd"] == 0.016
    assert firmware.Replay(read_program(b"G1 X1 F600\n", "t"), SHIPPED).snaps[0].jd == 0.016
    conf = firmware.as_configured(SHIPPED)
    assert firmware.Replay(read_program(b"G1 X1 F600\n", "t"), conf).snaps[0].jd == 0.013


def test_the_files_lower_junctions_give_way_and_come_back():
    """Classic jerk below the hardware's is raised, above it kept; a lower M205 J is raised;
    after the last move the file's own come back."""
    text = "\n".join([
        "M205 X8 Y10", "G1 X10 Y10 F3000", "M205 X30 Y30", "G1 X20 Y10", "M205 J0.005",
        "G1 X20 Y20", "M205 X12 Y25", "G1 X30 Y20", "M84", ""]).encode()
    prog = read_program(text, "t")
    ov = firmware.accel_override(prog, SHIPPED)
    assert {prog.lines[k].strip(): v for k, v in ov.lines.items()} == {
        b"M205 X8 Y10": ["M205 X20 Y20"], b"M205 J0.005": ["M205 J0.016"],
        b"M205 X12 Y25": ["M205 X20"]}
    assert ov.junction == {"jd": 0.016, "jerk_x": 20.0, "jerk_y": 20.0}
    # (the file's M205 J0.005 is not given back: classic jerk is in force at the end)
    assert ov.restore == {"jerk_x": 12.0}
    lim = firmware.move_limits(prog, SHIPPED, override=ov)
    assert lim.jerk_mm_s[:, :2].tolist()[0] == [20.0, 20.0]
    assert lim.jerk_mm_s[:, :2].tolist()[1] == [30.0, 30.0]
    assert math.isnan(lim.jerk_mm_s[2, 0]) and lim.jd_mm[2] == 0.016
    assert lim.jerk_mm_s[:, :2].tolist()[3] == [20.0, 25.0]
    assert firmware.override_restore_texts(ov) == ["M205 X12"]
    assert "junctions M205 X20 Y20 mm/s (classic jerk), M205 J0.016 mm" in \
        firmware.by_flavour("marlin").describe_accels(ov)
    # without a hardware limit, and under --accel file, the file's stand
    assert firmware.accel_override(prog, with_jerk(SHIPPED, None)) is None
    assert firmware.accel_override(prog, SHIPPED, "file") is None


def test_klipper_square_corner_velocity_gives_way():
    kl = with_jerk(SHIPPED, {"x": 20.0, "y": 20.0}, "klipper")
    text = b"SET_VELOCITY_LIMIT SQUARE_CORNER_VELOCITY=1 ACCEL=500\nG1 X10 Y10 F3000\nM84\n"
    prog = read_program(text, "t")
    ov = firmware.accel_override(prog, kl)
    assert list(ov.lines.values()) == [
        ["SET_VELOCITY_LIMIT ACCEL=3000 SQUARE_CORNER_VELOCITY=10.9"]]
    assert ov.restore == {"accel_print": 500.0, "accel_travel": 500.0, "scv": 1.0}
    assert firmware.override_restore_texts(ov) == [
        "SET_VELOCITY_LIMIT ACCEL=500 SQUARE_CORNER_VELOCITY=1"]


def test_the_profile_reads_and_writes_the_hardware_limit(tmp_path):
    d = profile_to_dict(SHIPPED)
    assert d["limits"]["axis_jerk_mm_s"] == {"x": 20.0, "y": 20.0}
    assert parse_profile(d, "p.yaml", tmp_path).limits.axis_jerk_mm_s == {"x": 20.0, "y": 20.0}
    del d["limits"]["axis_jerk_mm_s"]
    assert parse_profile(d, "p.yaml", tmp_path).limits.axis_jerk_mm_s is None
    d["limits"]["axis_jerk_mm_s"] = {"x": 20.0, "y": -1.0}
    with pytest.raises(ProfileError, match="axis_jerk_mm_s"):
        parse_profile(d, "p.yaml", tmp_path)
    d["limits"]["axis_jerk_mm_s"] = {"x": 20.0}
    with pytest.raises(ProfileError, match="axis_jerk_mm_s"):
        parse_profile(d, "p.yaml", tmp_path)
