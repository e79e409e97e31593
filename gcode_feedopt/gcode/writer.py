"""Writers: a Schedule back into G-code.

*re-feedrated* (default): each original move is split into as few sub-moves as needed for
the F values to follow the planned speed within ``SPEED_TOL`` (relative, with a floor of
``SPEED_TOL_ABS_MM_S``); each sub-move's F is its average planned speed, so the time of every
piece — and of the file — is the plan's. E is split exactly in proportion to length (absolute
and relative E), each original move still ends at its original coordinates (the last piece
reuses the original number texts, or for relative moves the exact decimal remainder), arcs are
split into sub-arcs (G2/G3 with I/J recomputed), the modal F is restored before any untouched
motion line that relies on it, and no piece is shorter than 1/max_lines_per_s.

Where a slow-down plan (optimize.slowdown) runs a stretch at a lower acceleration than the
firmware's, the writer cuts the moves at the plan's cell runs and tells the firmware each
run's acceleration and junction rule (Marlin ``M204 P T`` and, when the file uses classic jerk,
``M205 X Y``; Klipper ``SET_VELOCITY_LIMIT ACCEL SQUARE_CORNER_VELOCITY``), restoring the
settings in force before the next line that is not a slowed piece or a comment and at the
end: the firmware then runs the plan itself, one line per run, instead of a staircase of F
values at full acceleration (which runs ~2 % slower than planned, with the acceleration bursts
the plan avoided).

Under ``--accel plan`` (vm.firmware.accel_override) the plan runs at its own accelerations where
the file sets lower ones: right after each such line of the file (after the homing that follows
it, if any) one line sets the plan's again, and after the last move the file's own come back.

*sampled* (``mode="sampled"``): one G1 per Ts of the plan; a header comment states Ts.

Every other line passes through byte for byte. The writer returns, with the bytes, a tag for
each output line so :mod:`verify` can check the invariants independently.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import __version__
from ..vm.firmware import override_restore_texts
from .firmware_lines import (_OVERRIDE_WHY, _RESTORE_WHY, _AccelState, _ClampState,
                             _PlanLimits)
from .metadata import MetadataUpdater
from .motion_lines import _Emitter, _fmt
from .path import SEG_LINE, Path
from .reader import IDENT_PREFIX, Program
from .schedule import Schedule, SlowdownCells

#: Relative speed band a sub-move may span (the F written is its average speed).
SPEED_TOL = 0.05
#: ... but never finer than this, mm/s.
SPEED_TOL_ABS_MM_S = 1.0

#: Sampled mode: an interval shorter than this joins the next one, s.
SLIVER_S = 1e-4

# Tags of output lines.
T_ORIG, T_META, T_NEW, T_RESTORE, T_IDENT, T_ACCEL = 0, 1, 2, 3, 4, 5

#: A slowed cell (plan scale r below this) gets its own acceleration line; above it the
#: firmware's own settings hold.
SCALE_OVERRIDE_BELOW = 0.999
#: At the ends of a cell run, an interval shorter than this many Ts joins its neighbour.
RUN_SLIVER = 0.25


@dataclass
class WriteResult:
    data: bytes
    #: per output line: (tag, index) — input line index for T_ORIG/T_META, move index for T_NEW
    tags: list
    lines_written: int
    moves_changed: int
    sub_moves: int
    #: lines written to set and restore the firmware's acceleration around slowed stretches
    accel_lines: int = 0
    #: the lines that set the plan's limits on a printer configured lower (``_PlanLimits``)
    plan_limit_lines: tuple = ()
    #: lines re-setting the plan's acceleration after the file's lines that lower it, and
    #: giving the file's own back after the last move (``--accel plan``, vm.firmware
    #: .AccelOverride)
    override_lines: int = 0


def _ending(line: bytes) -> bytes:
    if line.endswith(b"\r\n"):
        return b"\r\n"
    if line.endswith(b"\n"):
        return b"\n"
    return b""


def segment_times(schedule: Schedule, path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(N,) time the motion of each segment starts and ends, s (from the sampled s(t))."""
    s = schedule.s_mm
    ts = schedule.ts_s
    t = np.arange(s.size) * ts
    lo = path.s0_mm[:-1]
    hi = path.s0_mm[1:]
    # start: last sample with s <= lo, then interpolate to the exact crossing
    t_start = _crossing(s, t, lo, leave=True)
    t_end = _crossing(s, t, hi, leave=False)
    return t_start, t_end


def _crossing(s, t, level, leave: bool):
    """Time s(t) leaves ``level`` (leave=True: last instant at level) or first reaches it."""
    if leave:
        j = np.searchsorted(s, level, side="right") - 1
    else:
        j = np.searchsorted(s, level, side="left") - 1
    j = np.clip(j, 0, s.size - 2)
    s0 = s[j]
    s1 = s[j + 1]
    ds = s1 - s0
    frac = np.where(ds > 0, (level - s0) / np.where(ds > 0, ds, 1.0), 1.0 if not leave else 0.0)
    return t[j] + np.clip(frac, 0.0, 1.0) * (t[j + 1] - t[j])


def _firmware_band(v_plan: np.ndarray, s_mid: np.ndarray, t_mid: np.ndarray, L: float,
                   ta: float, tb: float, accel: float) -> float | None:
    """If the firmware, given one move with F = the plan's peak speed, would reproduce the
    planned speed (its own trapezoid: accelerate at ``accel`` from the entry speed, cruise at
    F, brake at ``accel`` to the exit speed) within the speed tolerance, return that F."""
    if accel <= 0 or not np.isfinite(accel):
        return None
    vpk = float(v_plan.max())
    v0 = max(float(v_plan[0]) - accel * (t_mid[0] - ta), 0.0)
    v1 = max(float(v_plan[-1]) - accel * (tb - t_mid[-1]), 0.0)
    v_fw = np.sqrt(np.minimum(np.minimum(vpk * vpk, v0 * v0 + 2 * accel * s_mid),
                              v1 * v1 + 2 * accel * np.maximum(L - s_mid, 0.0)))
    band = max(SPEED_TOL * vpk, SPEED_TOL_ABS_MM_S)
    if np.max(np.abs(v_fw - v_plan)) <= band:
        return vpk
    return None


#: Segments per batch of :func:`single_piece_speeds` (bounds its temporary arrays: a batch
#: holds about this many segments' samples, a few MB, instead of the whole file's).
_BATCH_SEGMENTS = 8192


def single_piece_speeds(s_mm: np.ndarray, ts_s: float, s0_mm: np.ndarray, t_start_s: np.ndarray,
                        t_end_s: np.ndarray, accel_mm_s2: np.ndarray | None,
                        sampled: bool) -> np.ndarray:
    """(N,) the speed of the one line :func:`_pieces` writes for each segment, mm/s; NaN where
    it may write more than one (those go through :func:`_pieces` itself).

    Batched over all segments: a segment without a sample inside it (one line at its average
    speed) and, unless ``sampled``, a segment whose plan is the firmware's own trapezoid
    (:func:`_firmware_band`, one line at the peak speed). The arithmetic is :func:`_pieces`'s
    and :func:`_firmware_band`'s element for element (the same operations in the same order,
    maxima instead of sums), so the speeds — and the F texts — are bit-identical
    (tests/gcode/test_writer_fast.py).

    s_mm: (K,) the schedule; s0_mm: (N+1,) segment boundaries; t_start_s, t_end_s: (N,) motion
    start and end of each segment (:func:`segment_times`); accel_mm_s2: (N,) or None."""
    n = s0_mm.size - 1
    lo = s0_mm[:-1]
    hi = s0_mm[1:]
    L = hi - lo
    j0 = np.searchsorted(s_mm, lo, side="right")
    j1 = np.searchsorted(s_mm, hi, side="left")
    n_in = np.maximum(j1 - j0, 0)
    out = np.full(n, np.nan)
    trivial = (n_in == 0) | (L <= 0)
    out[trivial] = L[trivial] / np.maximum(t_end_s - t_start_s, 1e-9)[trivial]
    if sampled or accel_mm_s2 is None:
        return out
    acc = np.asarray(accel_mm_s2, dtype=float)
    cand = np.flatnonzero(~trivial & (acc > 0) & np.isfinite(acc))
    for b in range(0, cand.size, _BATCH_SEGMENTS):
        sel = cand[b:b + _BATCH_SEGMENTS]
        ok, vpk = _band_batch(s_mm, ts_s, lo[sel], L[sel], j0[sel], n_in[sel], t_start_s[sel],
                              t_end_s[sel], acc[sel])
        out[sel[ok]] = vpk[ok]
    return out


def _band_batch(s_mm, ts_s, lo, L, j0, n_in, ta, tb, accel):
    """:func:`_firmware_band` of M segments at once: (M,) accepted, (M,) peak speed mm/s.

    Each segment's points (start, its n_in samples, end) are laid out one after the other
    (``off``: (M,) first point of each); its n_in + 1 intervals follow the same layout with
    the interval that would join two segments left out (``istart``: (M,) first interval)."""
    m = lo.size
    npts = n_in + 2
    off = np.concatenate([[0], np.cumsum(npts)[:-1]])
    total = int(off[-1] + npts[-1])
    u = np.empty(total)
    t = np.empty(total)
    u[off] = 0.0
    t[off] = ta
    u[off + n_in + 1] = 1.0
    t[off + n_in + 1] = tb
    seg = np.repeat(np.arange(m), n_in)
    local = np.arange(seg.size) - np.repeat(np.cumsum(n_in) - n_in, n_in)
    j = j0[seg] + local
    pos = off[seg] + 1 + local
    u[pos] = (s_mm[j] - lo[seg]) / L[seg]
    t[pos] = j * ts_s
    keep = np.ones(total - 1, dtype=bool)
    keep[off[1:] - 1] = False
    nint = n_in + 1
    istart = off - np.arange(m)
    Lr = np.repeat(L, nint)
    du = (u[1:] - u[:-1])[keep] * Lr
    dt = (t[1:] - t[:-1])[keep]
    v = np.where(dt > 0, du / np.where(dt > 0, dt, 1.0), 0.0)
    s_mid = (u[:-1] + u[1:])[keep] * 0.5 * Lr
    t_mid = (t[:-1] + t[1:])[keep] * 0.5
    vpk = np.maximum.reduceat(v, istart)
    last = istart + n_in
    v0 = np.maximum(v[istart] - accel * (t_mid[istart] - ta), 0.0)
    v1 = np.maximum(v[last] - accel * (tb - t_mid[last]), 0.0)
    a2 = np.repeat(2 * accel, nint)
    vpk_r = np.repeat(vpk, nint)
    v0_r = np.repeat(v0, nint)
    v1_r = np.repeat(v1, nint)
    v_fw = np.sqrt(np.minimum(np.minimum(vpk_r * vpk_r, v0_r * v0_r + a2 * s_mid),
                              v1_r * v1_r + a2 * np.maximum(Lr - s_mid, 0.0)))
    err = np.maximum.reduceat(np.abs(v_fw - v), istart)
    band = np.maximum(SPEED_TOL * vpk, SPEED_TOL_ABS_MM_S)
    return err <= band, vpk


def _pieces(u_pts: np.ndarray, t_pts: np.ndarray, L: float, min_dt: float, sampled: bool,
            accel: float = 0.0):
    """Split one segment into as few pieces as keep F within the speed tolerance of the plan.

    u_pts, t_pts: (P,) fraction of the segment and time at the segment's start, its interior
    samples and its end. ``accel``: the acceleration the firmware uses on this segment.
    Returns a list of (u_end, speed_mm_s)."""
    if u_pts.size <= 2 or L <= 0:
        dt = max(t_pts[-1] - t_pts[0], 1e-9)
        return [(1.0, L / dt)]
    du = np.diff(u_pts) * L
    dt = np.diff(t_pts)
    v = np.where(dt > 0, du / np.where(dt > 0, dt, 1.0), 0.0)
    if not sampled:
        s_mid = (u_pts[:-1] + u_pts[1:]) * 0.5 * L
        t_mid = (t_pts[:-1] + t_pts[1:]) * 0.5
        f_one = _firmware_band(v, s_mid, t_mid, L, t_pts[0], t_pts[-1], accel)
        if f_one is not None:
            return [(1.0, f_one)]
    if sampled:
        # one piece per sample interval; slivers (a crossing a hair before a sample) join the
        # next interval so no line is written for a sub-microsecond piece
        out = []
        j0 = 0
        for j in range(du.size):
            last = j == du.size - 1
            if not last and (t_pts[j + 1] - t_pts[j0]) < SLIVER_S:
                continue
            d = float(np.sum(du[j0:j + 1]))
            tt = float(t_pts[j + 1] - t_pts[j0])
            if d > 0:
                out.append((float(u_pts[j + 1]), d / max(tt, 1e-9)))
            j0 = j + 1
        if not out:
            return [(1.0, L / max(t_pts[-1] - t_pts[0], 1e-9))]
        out[-1] = (1.0, out[-1][1])
        return out
    out = []
    j0 = 0
    n = du.size
    vmin = vmax = v[0]
    t_piece0 = t_pts[0]
    for j in range(1, n + 1):
        end = j == n
        if not end:
            vj = v[j]
            lo, hi = min(vmin, vj), max(vmax, vj)
            band = max(SPEED_TOL * hi, SPEED_TOL_ABS_MM_S)
            if hi - lo <= band or (t_pts[j] - t_piece0) < min_dt:
                vmin, vmax = lo, hi
                continue
        # close the piece [j0, j)
        d = float(np.sum(du[j0:j]))
        tt = float(t_pts[j] - t_pts[j0])
        if d > 0:
            out.append((float(u_pts[j]), d / max(tt, 1e-9)))
        j0 = j
        t_piece0 = t_pts[j]
        if not end:
            vmin = vmax = v[j]
    return _close_pieces(out, u_pts, t_pts, L, min_dt)


def _split_pieces(u_pts: np.ndarray, t_pts: np.ndarray, L: float, min_dt: float):
    """``_pieces(u_pts, t_pts, L, min_dt, sampled=False, accel=0.0)`` for a segment with
    samples inside it (u_pts.size > 2, L > 0): the same greedy split on Python floats instead
    of numpy scalars (a segment holds a handful of samples, where numpy's per-call cost is
    all there is). The piece lengths are still ``np.sum`` of the same slices (numpy sums in
    its own order), so every piece is bit-identical (tests/gcode/test_writer_fast.py)."""
    du = np.diff(u_pts) * L
    dt = np.diff(t_pts)
    v = np.where(dt > 0, du / np.where(dt > 0, dt, 1.0), 0.0).tolist()
    tl = t_pts.tolist()
    ul = u_pts.tolist()
    out = []
    j0 = 0
    n = len(v)
    vmin = vmax = v[0]
    t_piece0 = tl[0]
    for j in range(1, n + 1):
        end = j == n
        if not end:
            vj = v[j]
            lo, hi = min(vmin, vj), max(vmax, vj)
            band = max(SPEED_TOL * hi, SPEED_TOL_ABS_MM_S)
            if hi - lo <= band or (tl[j] - t_piece0) < min_dt:
                vmin, vmax = lo, hi
                continue
        d = float(np.sum(du[j0:j]))
        tt = tl[j] - tl[j0]
        if d > 0:
            out.append((ul[j], d / max(tt, 1e-9)))
        j0 = j
        t_piece0 = tl[j]
        if not end:
            vmin = vmax = v[j]
    return _close_pieces(out, u_pts, t_pts, L, min_dt)


def _close_pieces(out, u_pts, t_pts, L, min_dt):
    """The end of a greedy split: one piece at the average speed if none closed, a last piece
    shorter than min_dt merged into the one before it, and the last piece ending at u = 1."""
    if not out:
        return [(1.0, L / max(t_pts[-1] - t_pts[0], 1e-9))]
    if len(out) > 1:
        u_a = out[-3][0] if len(out) > 2 else 0.0
        u_b = out[-2][0]
        if t_pts[-1] - _t_of(u_pts, t_pts, u_b) < min_dt:
            t_a = _t_of(u_pts, t_pts, u_a)
            out = out[:-2] + [(1.0, (1.0 - u_a) * L / max(t_pts[-1] - t_a, 1e-9))]
    out[-1] = (1.0, out[-1][1])
    return out


def _t_of(u_pts, t_pts, u):
    return float(np.interp(u, u_pts, t_pts))


#: a planned segment is written as one line at its peak speed when the plan's acceleration is
#: the firmware's within this fraction (slow-down cells scaled by r ≥ SCALE_OVERRIDE_BELOW)
PEAK_ACCEL_MATCH = 0.005


def plan_peaks(schedule: Schedule, accel_mm_s2: np.ndarray | None, n: int) -> np.ndarray | None:
    """(N,) the peak speed of every segment the plan made one firmware trapezoid at the
    acceleration the firmware will use (``accel_mm_s2``) between junctions that F does not
    set (plan.kinematic.segment_plan ``exact``), NaN elsewhere; None when the plan does not
    say (``schedule.segment_plan``: kinematic and slow-down plans do).

    One line with F = that peak is what the firmware plans: the same entry and exit junctions
    (its look-ahead is the plan's), the same acceleration and the same top speed. Read from the
    samples instead, the peak is the fastest sample interval's mean speed, which is lower (by
    up to a·Ts/2 where the segment peaks between samples), and a short segment that starts or
    ends near rest fails the speed-band check of :func:`_firmware_band` and is split into a
    staircase of lines: both make the written file slower than the plan."""
    sp = schedule.segment_plan
    if sp is None or accel_mm_s2 is None:
        return None
    peak = np.asarray(sp.peak_mm_s, float)
    acc = np.asarray(sp.accel_mm_s2, float)
    fw = np.asarray(accel_mm_s2, float)
    if peak.shape != (n,) or fw.shape != (n,):
        return None
    ok = ((np.abs(acc - fw) <= PEAK_ACCEL_MATCH * fw) & (peak > 0) & np.isfinite(peak)
          & np.asarray(sp.exact, bool))
    return np.where(ok, peak, np.nan)


def _cell_runs(cells: SlowdownCells, cell_range: list, k: int, lo: float, hi: float):
    """Runs of equal (acceleration, scale) among the planning cells of segment k (cells
    ``cell_range[k]`` to ``cell_range[k + 1]``): list of (s_start, s_end, key) with key None
    where the cells are not slowed; the feed cap of each run (mm/s); and each run's peak speed
    in the plan (mm/s; None when ``cells`` has no ``vpeak_mm_s`` or classic jerk sets a
    junction at either end of the segment)."""
    c0, c1 = cell_range[k], cell_range[k + 1]
    peaks = cells.vpeak_mm_s
    jerk = cells.jerk_junction
    if jerk is not None and (jerk[c0] or jerk[c1]):
        peaks = None  # classic jerk at an end: the junction depends on F (plan_peaks)
    runs, vcap, vpk = [], [], []
    for c in range(c0, c1):
        r = float(cells.scale[c])
        key = None if r >= SCALE_OVERRIDE_BELOW else (math.floor(float(cells.accel_mm_s2[c])), r)
        a, b = float(cells.s0_mm[c]), float(cells.s0_mm[c + 1])
        vc = float(cells.vcap_mm_s[c])
        pk = math.inf if peaks is None else float(peaks[c])
        if runs and (runs[-1][2] == key or (key is not None and runs[-1][2] is not None
                                            and runs[-1][2][0] == key[0])):
            runs[-1] = (runs[-1][0], b, runs[-1][2])
            vcap[-1] = max(vcap[-1], vc)
            vpk[-1] = max(vpk[-1], pk)
        else:
            runs.append((a, b, key))
            vcap.append(vc)
            vpk.append(pk)
    if not runs:
        return [(lo, hi, None)], [math.inf], None
    runs[0] = (lo, runs[0][1], runs[0][2])
    runs[-1] = (runs[-1][0], hi, runs[-1][2])
    return runs, vcap, (None if peaks is None else vpk)


def _slowed_segments(cells: SlowdownCells, n: int):
    """(N,) bool, the segments with a slowed cell (scale below SCALE_OVERRIDE_BELOW; None when
    no segment has one), and the first cell of every segment, (N+1,) list (:func:`_cell_runs`)."""
    parent = np.asarray(cells.parent)
    cell_range = np.searchsorted(parent, np.arange(n + 1)).tolist()
    hit = np.asarray(cells.scale) < SCALE_OVERRIDE_BELOW
    slowed = np.zeros(n, bool)
    slowed[parent[hit]] = True
    return (slowed if slowed.any() else None), cell_range


def _run_pieces(s, ts, runs, lo, L, ta, tb, min_dt, accel_default, vcap, vpk=None):
    """Pieces (u_end over the whole segment, speed) of a segment cut at its cell runs, and the
    index of each run's first piece.

    With the plan's peak speed of every run (``vpk``): one piece per run at that speed. Within
    a run the acceleration is one and cells of one move meet without a junction rule, so the
    plan there is one firmware trapezoid (from the junction speed before the run to the one
    after it, at the run's acceleration, capped at its peak): one line with F = the peak and
    the run's acceleration is what the firmware plans. Without: each run split by
    :func:`_pieces` from the sampled schedule with the acceleration the firmware will use on
    it and its speeds kept within ``vcap`` (per run, mm/s)."""
    if vpk is not None:
        first = list(range(len(runs)))
        pieces = [((sb - lo) / L, min(p, c)) for (_, sb, _), p, c in zip(runs, vpk, vcap)]
        pieces[-1] = (1.0, pieces[-1][1])
        return pieces, first
    pieces, first = [], []
    for n, (sa, sb, key) in enumerate(runs):
        j0 = int(np.searchsorted(s, sa, side="right"))
        j1 = int(np.searchsorted(s, sb, side="left"))
        t_a = ta if n == 0 else _time_at(s, ts, sa)
        t_b = tb if n == len(runs) - 1 else _time_at(s, ts, sb)
        Ls = sb - sa
        u_a, u_b = (sa - lo) / L, (sb - lo) / L
        u_pts = np.concatenate([[0.0], (s[j0:j1] - sa) / Ls, [1.0]]) if Ls > 0 else np.array([0.0, 1.0])
        t_pts = np.concatenate([[t_a], np.arange(j0, j1) * ts, [t_b]])
        if u_pts.size > 3:
            # a sliver at either end of the run (its boundary a hair from a sample) joins the
            # interval next to it: its crossing time is interpolated, so its speed is not
            # the plan's and would set the run's peak
            keep = np.ones(u_pts.size, bool)
            keep[1] = t_pts[1] - t_pts[0] >= RUN_SLIVER * ts
            keep[-2] = t_pts[-1] - t_pts[-2] >= RUN_SLIVER * ts
            u_pts, t_pts = u_pts[keep], t_pts[keep]
        acc = accel_default if key is None else float(key[0])
        sub = _pieces(u_pts, t_pts, Ls, min_dt, False, acc)
        first.append(len(pieces))
        # no piece above the run's feed cap (the plan's cruise there)
        pieces.extend((u_a + u * (u_b - u_a), min(v, vcap[n])) for u, v in sub)
    pieces[-1] = (1.0, pieces[-1][1])
    return pieces, first


def _time_at(s, ts, level):
    """First time the schedule reaches ``level`` (interpolated between samples), s."""
    j = int(np.clip(np.searchsorted(s, level, side="left") - 1, 0, s.size - 2))
    ds = s[j + 1] - s[j]
    frac = (level - s[j]) / ds if ds > 0 else 1.0
    return (j + min(max(frac, 0.0), 1.0)) * ts


def write(program: Program, path: Path, schedule: Schedule, profile, *, mode: str = "refeed",
          accel_mm_s2: np.ndarray | None = None, fast: bool = True,
          cells: SlowdownCells | None = None,
          settings=None, clamp=None, feed_cap_mm_s: np.ndarray | None = None,
          run_settings: str = "", override=None) -> WriteResult:
    """Write the re-timed G-code (see module docstring).

    ``cells`` (a slow-down plan's ``schedule.cells``, gcode.schedule.SlowdownCells: each
    cell's boundaries, segment, scale and the plan's limits in it) with ``settings``
    (vm.firmware.accel_settings of the program): moves through slowed cells are cut at the
    cell runs and the firmware is told each run's acceleration (:class:`_AccelState`), in
    re-feedrated mode.

    ``clamp`` (vm.firmware.accel_clamp of the program under the plan's axis limits, or None):
    where the file lets the firmware accelerate harder than the plan (``--amax``, a profile's
    lower limits), a line setting the plan's limits (Marlin ``M201 X Y Z``, Klipper
    ``SET_VELOCITY_LIMIT ACCEL``) goes before the first move concerned and again after any
    line of the file that sets them; the file's own values come back after the last move.

    ``accel_mm_s2``: (N,) the acceleration the firmware will use on each segment; where the
    plan follows the firmware's own trapezoid, one line with F = the plan's peak speed
    reproduces it, so no extra lines are written.

    ``override`` (vm.firmware.accel_override, ``--accel plan``): right after each line of the
    file that sets an acceleration below the plan's (or after the homing that follows it), a
    line setting the plan's value again (Marlin ``M204 P.. T..`` / ``M201 X.. Y..``, Klipper
    ``SET_VELOCITY_LIMIT ACCEL=..``, with a ``; gcode-feedopt:`` comment); after the last move
    the file's own values in force there. ``settings`` and ``clamp`` are then those the
    override leaves in force, so slowed stretches and clamps restore the plan's values.

    ``run_settings``: what the run was made with, recorded in brackets on the ident line
    (pipeline.run_settings: ``batch`` re-processes an output whose settings differ).

    ``feed_cap_mm_s``: (N,) no line of segment k is written faster than this (the speed
    policy's ceiling, plan.speed.feed_ceiling; None: no cap).

    ``fast``: decide the moves that stay one line for all segments at once
    (:func:`single_piece_speeds`) and write them with :meth:`_Emitter.one_line`; every other
    move goes through :func:`_pieces` and :meth:`_Emitter.pieces_lines`. ``False`` sends every
    move through those two (the reference the fast path is tested against: same bytes)."""
    sampled = mode == "sampled"
    fw = profile.firmware
    min_dt = 0.0 if sampled else 1.0 / fw.max_lines_per_s
    t_start, t_end = segment_times(schedule, path)
    s = schedule.s_mm
    ts = schedule.ts_s
    seg_of_move = {int(m): k for k, m in enumerate(path.move_index)}
    moves = program.moves
    emitter = _Emitter(program, None if feed_cap_mm_s is None else {
        moves[int(m)].line_no: float(c) for m, c in zip(path.move_index, feed_cap_mm_s)})
    move_at_line = {mv.line_no: i for i, mv in enumerate(moves)}
    total_s = schedule.duration_s
    meta = MetadataUpdater(program, total_s)
    # elapsed time at each line: start of the next segment's motion after it
    seg_lines = np.array([moves[int(m)].line_no for m in path.move_index], dtype=np.int64)
    k_next = np.searchsorted(seg_lines, np.arange(len(program.lines)), side="right")
    t_at_line = (np.where(k_next < t_start.size, t_start[np.minimum(k_next, t_start.size - 1)],
                          total_s) if t_start.size else np.full(k_next.size, total_s)).tolist()
    one_speed = (single_piece_speeds(s, ts, path.s0_mm, t_start, t_end, accel_mm_s2, sampled)
                 if fast else None)
    peaks = None if sampled else plan_peaks(schedule, accel_mm_s2, path.n_segments)
    if one_speed is not None:
        if peaks is not None:
            one_speed = np.where(np.isnan(peaks), one_speed, peaks)
        one_speed = one_speed.tolist()
    if peaks is not None:
        peaks = peaks.tolist()
    acc_state = slowed = cell_range = None
    if cells is not None and settings is not None and not sampled:
        slowed, cell_range = _slowed_segments(cells, path.n_segments)
        if slowed is not None:
            acc_state = _AccelState(settings)
            if one_speed is not None:
                for k in np.flatnonzero(slowed).tolist():
                    one_speed[k] = math.nan
    last_new = -1  # index in ``out`` after the last re-timed line
    clamp_state = _ClampState(clamp) if clamp is not None else None
    last_mi = -1  # the last move (for the clamp's restore)
    fw_conf = profile.firmware
    plan_limits = (_PlanLimits(fw_conf, settings) if settings is not None and (
        fw_conf.configured_accel_mm_s2 is not None or fw_conf.configured_max_accel_mm_s2 is not None)
        else None)
    last_move = -1  # the last move (for the plan limits' restore)
    ov_lines = override.lines if override is not None else {}
    n_override = 0

    out: list[bytes] = []
    tags: list = []
    first_ending = _ending(program.lines[0]) or b"\n"
    ident = (IDENT_PREFIX + f" {__version__}".encode() +
             (f" (mode sampled, Ts = {ts * 1000:g} ms: one G1 per sample)".encode() if sampled else b"")
             + (f" [{run_settings}]".encode() if run_settings else b"")
             + first_ending)
    orig_feed = 0.0  # modal F of the original file at this point, mm/s
    cur_feed = 0.0  # modal F the firmware has from our output, mm/s
    moves_changed = 0
    sub_moves = 0
    for i, raw in enumerate(program.lines):
        if i == 1 or (i == 0 and len(program.lines) == 1):
            if i == 0:
                out.append(raw if raw.endswith(b"\n") else raw + first_ending)
                tags.append((T_ORIG, i))
                out.append(ident)
                tags.append((T_IDENT, -1))
                continue
            out.append(ident)
            tags.append((T_IDENT, -1))
        mi = move_at_line.get(i)
        if acc_state is not None and acc_state.active is not None:
            # back to the settings in force before anything but a slowed move or a comment
            k = seg_of_move.get(mi) if mi is not None else None
            keep = (k is not None and slowed[k] and not moves[mi].fixed) or (
                mi is None and raw.lstrip()[:1] in (b";", b""))
            if not keep:
                lines = acc_state.restore(_ending(raw) or first_ending)
                out.extend(lines)
                tags.extend([(T_ACCEL, -1)] * len(lines))
                if lines and clamp_state is not None and acc_state.klipper and mi is not None:
                    clamp_state.set_to_want(mi)
        if mi is not None:
            last_move = mi
            if (plan_limits is not None and not plan_limits.done
                    and seg_of_move.get(mi) is not None and not moves[mi].fixed):
                lines = plan_limits.before_first(mi, _ending(raw) or first_ending)
                out.extend(lines)
                tags.extend([(T_ACCEL, -1)] * len(lines))
        if mi is not None and clamp_state is not None:
            lines = clamp_state.before_move(mi, _ending(raw) or first_ending)
            out.extend(lines)
            tags.extend([(T_ACCEL, -1)] * len(lines))
            last_mi = mi
        if mi is not None:
            mv = moves[mi]
            k = seg_of_move.get(mi)
            retime = k is not None and not mv.fixed
            if retime and slowed is not None and slowed[k]:
                lo, hi = float(path.s0_mm[k]), float(path.s0_mm[k + 1])
                runs, vcap, vpk = _cell_runs(cells, cell_range, k, lo, hi)
                acc_k = 0.0 if accel_mm_s2 is None else float(accel_mm_s2[k])
                pieces, first = _run_pieces(s, ts, runs, lo, hi - lo, float(t_start[k]),
                                            float(t_end[k]), min_dt, acc_k, vcap, vpk)
                semi = raw.find(b";")
                comment = raw[semi:].rstrip(b"\r\n") if semi >= 0 else b""
                ending = _ending(raw) or first_ending
                lines = emitter.pieces_lines(mv, pieces, ending, comment)
                starts = dict(zip(first, runs))
                for j, line in enumerate(lines):
                    run = starts.get(j)
                    if run is not None:
                        acc_lines = (acc_state.restore(ending) if run[2] is None
                                     else acc_state.set(run[2], mi, ending))
                        out.extend(acc_lines)
                        tags.extend([(T_ACCEL, -1)] * len(acc_lines))
                    out.append(line)
                    tags.append((T_NEW, mi))
                last_new = len(out)
                moves_changed += 1
                sub_moves += len(lines)
                cur_feed = pieces[-1][1]
                if "F" in mv.words:
                    orig_feed = float(mv.words["F"]) / 60.0
                continue
            if retime and one_speed is not None and not math.isnan(one_speed[k]):
                v = one_speed[k]
                semi = raw.find(b";")
                comment = raw[semi:].rstrip(b"\r\n") if semi >= 0 else b""
                out.append(emitter.one_line(mv, v, _ending(raw) or first_ending, comment))
                tags.append((T_NEW, mi))
                moves_changed += 1
                sub_moves += 1
                cur_feed = v
                if "F" in mv.words:
                    orig_feed = float(mv.words["F"]) / 60.0
                continue
            if retime:
                ta, tb = t_start[k], t_end[k]
                lo, hi = path.s0_mm[k], path.s0_mm[k + 1]
                j0 = np.searchsorted(s, lo, side="right")
                j1 = np.searchsorted(s, hi, side="left")
                inner_s = s[j0:j1]
                inner_t = np.arange(j0, j1) * ts
                L = hi - lo
                u_pts = np.concatenate([[0.0], (inner_s - lo) / L, [1.0]])
                t_pts = np.concatenate([[ta], inner_t, [tb]])
                text = raw.decode("latin-1")
                semi = text.find(";")
                comment = raw[semi:].rstrip(b"\r\n") if semi >= 0 else b""
                ending = _ending(raw) or first_ending
                if one_speed is not None and not sampled:
                    # NaN from the fast path: samples inside the segment and no single line
                    # reproduces them (_firmware_band refused it, or there is no accel)
                    pieces = _split_pieces(u_pts, t_pts, L, min_dt)
                    lines = emitter.split_lines(mv, pieces, ending, comment)
                else:
                    acc_k = 0.0 if accel_mm_s2 is None else float(accel_mm_s2[k])
                    if peaks is not None and not math.isnan(peaks[k]):
                        pieces = [(1.0, peaks[k])]
                    else:
                        pieces = _pieces(u_pts, t_pts, L, min_dt, sampled, acc_k)
                    lines = emitter.pieces_lines(mv, pieces, ending, comment)
                out.extend(lines)
                tags.extend([(T_NEW, mi)] * len(lines))
                moves_changed += 1
                sub_moves += len(lines)
                cur_feed = pieces[-1][1]
                if "F" in mv.words:
                    orig_feed = float(mv.words["F"]) / 60.0
                continue
            # an untouched motion line: restore the modal F it relies on
            if "F" not in mv.words and abs(cur_feed - mv.feed_mm_s) > 1e-9 and cur_feed > 0:
                out.append(f"G1 F{_fmt(mv.feed_mm_s * 60.0, 4)}".encode() + (_ending(raw) or first_ending))
                tags.append((T_RESTORE, mi))
            out.append(raw)
            tags.append((T_ORIG, i))
            cur_feed = orig_feed = mv.feed_mm_s
            continue
        # non-motion line
        new = meta.update(i, raw, t_at_line[i])
        if new is not None:
            out.append(new)
            tags.append((T_META, i))
        else:
            out.append(raw)
            tags.append((T_ORIG, i))
        if i in ov_lines and _ending(raw):
            # the file lowers an acceleration below the plan's: the plan's again
            for text in ov_lines[i]:
                out.append(text.encode() + _OVERRIDE_WHY + _ending(raw))
                tags.append((T_ACCEL, -1))
            n_override += len(ov_lines[i])
        f_word = _feed_only(raw)
        if f_word is not None:
            cur_feed = orig_feed = f_word
    accel_lines = 0
    if clamp_state is not None and last_mi >= 0:
        # the file's own limits back right after the last motion line
        last_line = moves[last_mi].line_no
        at = len(tags)
        while at > 0 and not (tags[at - 1] == (T_NEW, last_mi)
                              or tags[at - 1] == (T_ORIG, last_line)):
            at -= 1
        lines = clamp_state.restore(last_mi, first_ending)
        out[at:at] = lines
        tags[at:at] = [(T_ACCEL, -1)] * len(lines)
        accel_lines += clamp_state.lines
    if acc_state is not None:
        # the file ends in a slowed stretch (then comments): restore right after it
        lines = acc_state.restore(first_ending)
        out[last_new:last_new] = lines
        tags[last_new:last_new] = [(T_ACCEL, -1)] * len(lines)
        accel_lines += acc_state.lines
    if override is not None and override.restore and last_move >= 0:
        # the file's own accelerations back after the last motion line and what restores the
        # slowed stretches' settings and the clamp there
        at = _after_last_move(tags, last_move, moves[last_move].line_no)
        lines = [t.encode() + _RESTORE_WHY + first_ending for t in override_restore_texts(override)]
        out[at:at] = lines
        tags[at:at] = [(T_ACCEL, -1)] * len(lines)
        n_override += len(lines)
    accel_lines += n_override
    if plan_limits is not None and plan_limits.done and last_move >= 0:
        # the printer's configured limits back after the last motion line and what restores
        # the file's own and the slowed stretches' settings there
        at = _after_last_move(tags, last_move, moves[last_move].line_no)
        lines = plan_limits.restore(first_ending)
        out[at:at] = lines
        tags[at:at] = [(T_ACCEL, -1)] * len(lines)
        accel_lines += plan_limits.lines
    return WriteResult(data=b"".join(out), tags=tags, lines_written=len(out),
                       moves_changed=moves_changed, sub_moves=sub_moves,
                       accel_lines=accel_lines,
                       plan_limit_lines=plan_limits.set_lines if plan_limits is not None else (),
                       override_lines=n_override)


def _after_last_move(tags: list, last_move: int, last_line: int) -> int:
    """Index in the output after the last motion line and the lines of ours that follow it."""
    at = len(tags)
    while at > 0 and not (tags[at - 1] == (T_NEW, last_move)
                          or tags[at - 1] == (T_ORIG, last_line)):
        at -= 1
    while at < len(tags) and tags[at] == (T_ACCEL, -1):
        at += 1
    return at


def _feed_only(raw: bytes) -> float | None:
    """F of a `G0/G1 F...` line without axes (modal feed set), mm/s; else None."""
    text = raw.split(b";", 1)[0].strip().upper()
    if not text.startswith((b"G1", b"G0")) or b"F" not in text:
        return None
    toks = text.split()
    if toks[0] not in (b"G1", b"G0", b"G01", b"G00"):
        return None
    f = None
    for t in toks[1:]:
        if t[:1] in (b"X", b"Y", b"Z", b"E"):
            return None
        if t[:1] == b"F":
            try:
                f = float(t[1:]) / 60.0
            except ValueError:
                return None
    return f


def write_trajectory_csv(fh, schedule: Schedule, path: Path) -> None:
    """``t,x,y,z,e`` per sample of the plan (s, mm)."""
    s = schedule.s_mm
    pos = path.position(s)
    k = path.segment_at(s)
    L = path.length_mm[k]
    u = np.where(L > 0, (s - path.s0_mm[k]) / np.where(L > 0, L, 1.0), 0.0)
    e_start = np.concatenate([[0.0], np.cumsum(path.de_mm)])[:-1]
    e = e_start[k] + path.de_mm[k] * np.clip(u, 0, 1)
    t = np.arange(s.size) * schedule.ts_s
    arr = np.column_stack([t, pos, e])
    fh.write(b"t,x,y,z,e\n")
    np.savetxt(fh, arr, fmt=["%.4f", "%.5f", "%.5f", "%.5f", "%.5f"], delimiter=",")
