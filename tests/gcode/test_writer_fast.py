"""The writer's fast path (moves decided one line for all segments at once, written by
``_Emitter.one_line``) against the reference (every move through ``_pieces`` and
``_Emitter.pieces_lines``): the same bytes and tags, on real files, on schedules that are the
firmware's own plan and on schedules that are not (a slower plan, a plan with speed dips)."""

from __future__ import annotations

import time

import numpy as np
import pytest

from gcode_feedopt import firmware
from gcode_feedopt.gcode.path import build_path
from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.gcode.schedule import Schedule
from gcode_feedopt.gcode.motion_lines import _Emitter
from gcode_feedopt.gcode.pieces import (_firmware_band, _pieces, _split_pieces, segment_times,
                                        single_piece_speeds)
from gcode_feedopt.gcode.writer import write
from gcode_feedopt.plan.kinematic import plan_kinematic, writer_accel
from gcode_feedopt.profile import load_profile

from ..conftest import GCODE_DIR, REPO

PROFILE = load_profile("ender3pro")
BENCHY = GCODE_DIR / "cura-4.11_ender3_3dbenchy.gcode"
PRUSA = GCODE_DIR / "prusaslicer-2.6.1_mini_3dbenchy.gcode"
ARCS = GCODE_DIR / "slic3rpe-arcwelder_3dbenchy-arcs.gcode"


def _head(path, n_lines: int) -> bytes:
    """The first ``n_lines`` lines of a real file (cut at test time, never copied)."""
    if not path.exists():
        pytest.skip(f"{path} not found")
    return b"".join(path.read_bytes().splitlines(keepends=True)[:n_lines])


def _dip(sched: Schedule, period_s: float = 0.9, depth: float = 0.45) -> Schedule:
    """``sched`` followed at w(τ) = 1 − depth·max(0, sin 2πτ/period)^4 of its rate: speed
    dips inside moves, so the plan is no longer any firmware's trapezoid."""
    ts = sched.ts_s
    tau = np.arange(sched.s_mm.size) * ts
    w = 1.0 - depth * np.maximum(0.0, np.sin(2 * np.pi * tau / period_s)) ** 4
    t_new = np.concatenate([[0.0], np.cumsum(0.5 * (1 / w[1:] + 1 / w[:-1]) * ts)])
    k = int(np.ceil(t_new[-1] / ts)) + 1
    s = np.maximum.accumulate(np.interp(np.interp(np.arange(k) * ts, t_new, tau), tau, sched.s_mm))
    s[-1] = sched.s_mm[-1]
    return Schedule(ts_s=ts, s_mm=s, method="dip")


def _setup(data: bytes, profile=PROFILE):
    fw = profile.firmware
    prog = read_program(data, "t.gcode", flavour=fw.flavour, g91_relative_e=fw.g91_relative_e)
    path = build_path(prog)
    limits = firmware.move_limits(prog, profile)
    return prog, path, limits, writer_accel(path, profile, limits)


def _same(prog, path, sched, acc, mode, profile=PROFILE):
    fast = write(prog, path, sched, profile, mode=mode, accel_mm_s2=acc, fast=True)
    ref = write(prog, path, sched, profile, mode=mode, accel_mm_s2=acc, fast=False)
    assert fast.data == ref.data
    assert fast.tags == ref.tags
    assert (fast.lines_written, fast.moves_changed, fast.sub_moves) == \
        (ref.lines_written, ref.moves_changed, ref.sub_moves)
    return fast


CASES = {
    "benchy-6000": lambda: _head(BENCHY, 6000),
    "prusa-4000": lambda: _head(PRUSA, 4000),  # relative E, M73 progress lines
    "arcs-3000": lambda: _head(ARCS, 3000),  # G2/G3
    "butterfly": lambda: (REPO / "sample_gcode" / "butterfly.gcode").read_bytes(),
    "part": lambda: (REPO / "sample_gcode" / "part_prusaslicer.gcode").read_bytes(),
}


PAIRS = ([(c, "kinematic") for c in sorted(CASES)] + [(c, "dip") for c in sorted(CASES)]
         + [("benchy-6000", "vmax40"), ("part", "vmax40"), ("benchy-6000", "slicer-feed"),
            ("prusa-4000", "slicer-feed"), ("butterfly", "no-accel"), ("prusa-4000", "no-accel")])


@pytest.mark.parametrize("case,plan", PAIRS)
def test_fast_path_writes_the_reference_bytes(case, plan):
    prog, path, limits, acc = _setup(CASES[case]())
    if plan == "slicer-feed":
        sched = plan_kinematic(path, PROFILE, use_slicer_feed=True, fw_limits=limits)
    elif plan == "vmax40":
        # slower than the limits allow, written with the default limits' accelerations
        sched = plan_kinematic(path, PROFILE, vmax_mm_s=40.0, fw_limits=limits)
    else:
        sched = plan_kinematic(path, PROFILE, fw_limits=limits)
    if plan == "dip":
        sched = _dip(sched)
    if plan == "no-accel":
        acc = None
    res = _same(prog, path, sched, acc, "refeed")
    if plan == "dip":
        # the dips really leave the fast path: some moves are split
        assert res.sub_moves > res.moves_changed


@pytest.mark.parametrize("plan", ["kinematic", "dip"])
def test_fast_path_sampled(plan):
    # one line per 2 ms of print: the butterfly (a few seconds of print) keeps this quick
    prog, path, limits, acc = _setup(CASES["butterfly"]())
    sched = plan_kinematic(path, PROFILE, fw_limits=limits)
    if plan == "dip":
        sched = _dip(sched)
    _same(prog, path, sched, acc, "sampled")


@pytest.mark.parametrize("plan", ["kinematic", "dip"])
def test_single_piece_speeds_are_what_pieces_returns(plan):
    """Segment by segment: where the batch gives a speed, ``_pieces`` returns exactly one
    piece at that speed; where it gives NaN, ``_pieces`` splits the move or
    ``_firmware_band`` refuses it."""
    prog, path, limits, acc = _setup(_head(BENCHY, 3000))
    sched = plan_kinematic(path, PROFILE, fw_limits=limits)
    if plan == "dip":
        sched = _dip(sched)
    t_start, t_end = segment_times(sched, path)
    s, ts = sched.s_mm, sched.ts_s
    got = single_piece_speeds(s, ts, path.s0_mm, t_start, t_end, acc, sampled=False)
    min_dt = 1.0 / PROFILE.firmware.max_lines_per_s
    n_one = 0
    for k in range(path.n_segments):
        lo, hi = path.s0_mm[k], path.s0_mm[k + 1]
        j0 = np.searchsorted(s, lo, side="right")
        j1 = np.searchsorted(s, hi, side="left")
        L = hi - lo
        u_pts = np.concatenate([[0.0], (s[j0:j1] - lo) / L, [1.0]])
        t_pts = np.concatenate([[t_start[k]], np.arange(j0, j1) * ts, [t_end[k]]])
        pieces = _pieces(u_pts, t_pts, L, min_dt, False, float(acc[k]))
        if np.isnan(got[k]):
            du = np.diff(u_pts) * L
            dt = np.diff(t_pts)
            v = np.where(dt > 0, du / np.where(dt > 0, dt, 1.0), 0.0)
            band = _firmware_band(v, (u_pts[:-1] + u_pts[1:]) * 0.5 * L,
                                  (t_pts[:-1] + t_pts[1:]) * 0.5, L, t_pts[0], t_pts[-1],
                                  float(acc[k]))
            assert u_pts.size > 2 and band is None
            assert _split_pieces(u_pts, t_pts, L, min_dt) == _pieces(u_pts, t_pts, L, min_dt,
                                                                       False, 0.0)
        else:
            n_one += 1
            assert pieces == [(1.0, got[k])]
    assert n_one > 0.5 * path.n_segments


def test_one_line_is_the_one_piece_of_pieces_lines():
    """``one_line`` against ``pieces_lines`` with one piece, on every move of files with
    absolute and relative E, arcs, comments and CRLF endings."""
    srcs = [_head(BENCHY, 2000), _head(PRUSA, 2000), _head(ARCS, 2000),
            b"G91\r\nM83\r\nG1 X1.50 Y-0.0 E.5 F600 ; rel\r\nG2 X2 Y0 I1 J0 E0.100\r\n"]
    em_moves = 0
    for data in srcs:
        prog = read_program(data, "t.gcode")
        em = _Emitter(prog)
        for mv in prog.moves:
            for v in (12.3456, 0.01, 83.33333333):
                ref = em.pieces_lines(mv, [(1.0, v)], b"\r\n", b"; c")
                assert [em.one_line(mv, v, b"\r\n", b"; c")] == ref
                assert [em.one_line(mv, v, b"\n", b"")] == em.pieces_lines(mv, [(1.0, v)], b"\n", b"")
            em_moves += 1
    assert em_moves > 3000


def test_split_lines_are_pieces_lines():
    """``split_lines`` against ``pieces_lines`` with several pieces on every move of files
    with absolute and relative E and XYZ, arcs (handed to the reference) and comments."""
    rng = np.random.default_rng(9)
    srcs = [_head(BENCHY, 1500), _head(PRUSA, 1500), _head(ARCS, 1500),
            b"G91\nM83\nG1 X1.50 Y-0.3333 E.5 F600 ; rel\nG1 X2 Y0 Z0.25 E0.100\nG90\n"
            b"G92 X5 E2\nG1 X7.25 Y3 E2.5\n"]
    n = 0
    for data in srcs:
        prog = read_program(data, "t.gcode")
        em = _Emitter(prog)
        for mv in prog.moves:
            k = int(rng.integers(1, 6))
            u = np.sort(rng.uniform(0, 1, k - 1)).tolist() + [1.0]
            pieces = [(ui, float(v)) for ui, v in zip(u, rng.uniform(0.01, 90, k))]
            assert em.split_lines(mv, pieces, b"\n", b"; c") == \
                em.pieces_lines(mv, pieces, b"\n", b"; c")
            n += 1
    assert n > 2000


def test_fast_path_is_faster():
    """The point of the fast path, as a ratio (never an absolute time)."""
    prog, path, limits, acc = _setup(_head(BENCHY, 4000))
    sched = plan_kinematic(path, PROFILE, fw_limits=limits)

    def best(fast):
        t = []
        for _ in range(2):
            t0 = time.perf_counter()
            write(prog, path, sched, PROFILE, accel_mm_s2=acc, fast=fast)
            t.append(time.perf_counter() - t0)
        return min(t)

    assert best(True) < 0.5 * best(False)
