"""The firmware model's fast paths (blocks and per-move limits as arrays, limits looked up
from one snapshot per event) against the reference (move by move, reference.py): the same
arrays bit for bit, hence the same estimated time, on real files, on both flavours and on a
file that exercises every event the model honours."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest

from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.profile import load_profile
from gcode_feedopt.firmware import Replay, build_blocks, move_limits
from gcode_feedopt.vm.firmware import estimate_time_s

from ..conftest import GCODE_DIR, REPO
from . import reference

MARLIN = load_profile("ender3pro")
KLIPPER = dataclasses.replace(MARLIN, firmware=dataclasses.replace(
    MARLIN.firmware, flavour="klipper", g91_relative_e=False, minimum_cruise_ratio=0.3))
PROFILES = {"marlin": MARLIN, "klipper": KLIPPER}

REAL = {p.name: p for p in sorted(GCODE_DIR.glob("*.gcode"))}
SAMPLES = {p.name: p for p in [REPO / "sample_gcode" / "butterfly.gcode",
                               REPO / "sample_gcode" / "part_prusaslicer.gcode"]}

#: every event the models honour (or Klipper refuses), E-only moves, firmware retraction, arcs,
#: a dwell before the first move (lead-in), zero-length moves, a retraction while travelling,
#: Z with E, and an event after the last move
EVENTS = b"""G4 P250
M204 P1500 T2500 R1200
M201 X2000 Y1800 Z80 E4000
M203 X300 Y250 Z4 E20
M205 X8 Y9 Z0.3 E4
G28
G90
M82
G92 E0
G1 Z0.2 F600
G1 X10 Y10 F6000
G1 X40 Y12 E1.2 F1800
G1 E0.4 F2400
G1 X40 Y12
G1 E1.2
G1 X60 Y30 E2.0
G4 S0.5
M205 J0.02
G2 X80 Y30 I10 J0 E3.0
G3 X60 Y30 R10 E4.0
G10
G1 X70 Y40 F9000
G11
SET_VELOCITY_LIMIT VELOCITY=80 ACCEL=2200 SQUARE_CORNER_VELOCITY=6 MINIMUM_CRUISE_RATIO=0.4
M204 S2000
G1 X90 Y40 E5.0 F3000
G1 X90.0001 Y40 E5.001
G1 Z0.4
G1 X90 Y60 Z0.6 E5.8
M400
G1 X10 Y10 F12000
M205 X12 Y12
G1 X20 Y11 E6.0
G1 X30 Y10 E6.3
M221 S95
M220 S110
G1 X35 Y15 E5.9
G1 Z0.8 E6.0
M204 P900
M204 T1100
G1 E5.0
M221
M220 S-5
G1 X36 Y15 E6.5
G91
G1 X-5 Y5 E0.2
G90
M107
G4 P100
"""


def _same_blocks(a, b):
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.shape == y.shape and np.array_equal(x, y), f.name
        else:
            assert x == y, f.name


def _check(data: bytes, profile):
    fw = profile.firmware
    prog = read_program(data, "t.gcode", flavour=fw.flavour, g91_relative_e=fw.g91_relative_e,
                        retract_mm=fw.retract_mm, retract_speed_mm_s=fw.retract_speed_mm_s)
    _same_blocks(build_blocks(Replay(prog, profile)), reference.build_blocks(prog, profile))
    assert estimate_time_s(prog, profile) == reference.estimate_time_s(prog, profile)
    a, b = move_limits(prog, profile), reference.move_limits(prog, profile)
    for f in dataclasses.fields(a):
        assert np.array_equal(getattr(a, f.name), getattr(b, f.name), equal_nan=True), f.name
    return prog


@pytest.mark.parametrize("flavour", sorted(PROFILES))
def test_every_event(flavour):
    profile = PROFILES[flavour]
    prog = _check(EVENTS, profile)
    assert any(m.arc is not None for m in prog.moves)
    blocks = build_blocks(Replay(prog, profile))
    assert blocks.lead_s > 0 and np.any(blocks.dwell_after_s > 0)
    assert np.any(blocks.stop_after[:-1]) and np.any(blocks.accel != blocks.accel[0])
    if flavour == "marlin":
        assert np.any(np.isfinite(blocks.jerk_v)) and np.any(~np.isfinite(blocks.jerk_v))
    else:
        # Klipper's rules all reached: a retraction while travelling, the pseudo-accel, Z
        assert np.any(blocks.e_ratio < 0) and np.any(blocks.peak_accel < blocks.accel)
        assert np.any(blocks.accel < 100.0 + 1e-9)


@pytest.mark.parametrize("flavour", sorted(PROFILES))
@pytest.mark.parametrize("name", sorted(REAL))
def test_real_files(name, flavour):
    # a slice of each file (the reference is slow, most of all on arcs: chords one by one)
    lines = REAL[name].read_bytes().splitlines(keepends=True)
    _check(b"".join(lines[:8000 if "arc" in name else 20000]), PROFILES[flavour])


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_sample_files(name):
    _check(SAMPLES[name].read_bytes(), MARLIN)


def test_no_motion_blocks():
    # only E-free zero-length moves: no block, every dwell in the lead-in
    _check(b"G4 P200\nG1 X0 Y0 F600\nG4 S1\nG1 X0 Y0\n", MARLIN)


def test_fast_blocks_are_faster():
    """As a ratio (never an absolute time)."""
    path = GCODE_DIR / "cura-4.11_ender3_3dbenchy.gcode"
    if not path.exists():
        pytest.skip(f"{path} not found")
    data = b"".join(path.read_bytes().splitlines(keepends=True)[:20000])
    prog = read_program(data, "t.gcode")

    def best(build):
        t = []
        for _ in range(2):
            t0 = time.perf_counter()
            build()
            t.append(time.perf_counter() - t0)
        return min(t)

    assert (best(lambda: build_blocks(Replay(prog, MARLIN)))
            < 0.5 * best(lambda: reference.build_blocks(prog, MARLIN)))
