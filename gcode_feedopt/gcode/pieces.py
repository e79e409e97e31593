"""What each planned segment is written as: its pieces, for the writer.

A piece is ``(u_end, speed_mm_s)``: the fraction of the segment where it ends and the speed its
line is written at (F). Each original move is one segment of the Path; the writer
(gcode.writer) asks here how many lines it takes and at which F, and gcode.motion_lines turns
the pieces into text.

- :func:`segment_times`: when the plan starts and ends the motion of each segment;
- :func:`plan_peaks`: a segment the plan made one firmware trapezoid is one line at its peak
  (the plan says so: ``schedule.segment_plan``);
- :func:`single_piece_speeds` (batched :func:`_firmware_band`): the segments that stay one
  line, decided for all segments at once (the writer's fast path);
- :func:`_pieces`, :func:`_split_pieces`: the rest, split into as few pieces as keep F within
  ``SPEED_TOL`` of the plan (sampled mode: one piece per sample interval);
- :func:`_slowed_segments`, :func:`_cell_runs`, :func:`_run_pieces`: a slow-down plan's
  slowed segments, cut at the runs of cells of one acceleration (gcode.firmware_lines tells
  the firmware each run's).
"""

from __future__ import annotations

import math

import numpy as np

from .path import Path
from .schedule import Schedule, SlowdownCells

#: Relative speed band a sub-move may span (the F written is its average speed).
SPEED_TOL = 0.05
#: ... but never finer than this, mm/s.
SPEED_TOL_ABS_MM_S = 1.0
#: Sampled mode: an interval shorter than this joins the next one, s.
SLIVER_S = 1e-4
#: A slowed cell (plan scale r below this) gets its own acceleration line; above it the
#: firmware's own settings hold.
SCALE_OVERRIDE_BELOW = 0.999
#: At the ends of a cell run, an interval shorter than this many Ts joins its neighbour.
RUN_SLIVER = 0.25


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
    """(N,) the speed to write in one line for every segment the plan made one firmware
    trapezoid at the acceleration the firmware will use (``accel_mm_s2``): its peak between
    junctions that F does not set (plan.kinematic.segment_plan ``exact``), the plan's feed
    cap where classic jerk sets a junction at either end (Marlin's jerk rule takes the moves'
    nominal speeds, and the plan's junctions took the caps); NaN elsewhere; None when the plan
    does not say (``schedule.segment_plan``: kinematic and slow-down plans do).

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
    exact = np.asarray(sp.exact, bool)
    ok = (np.abs(acc - fw) <= PEAK_ACCEL_MATCH * fw) & (peak > 0) & np.isfinite(peak)
    speed = np.where(exact, peak, np.nan)
    if sp.cap_mm_s is not None and np.shape(sp.cap_mm_s) == (n,):
        # a classic-jerk junction at an end: one line at the plan's cap, the nominal speed
        # the plan's junctions assumed; the firmware's trapezoid still peaks where the plan's
        # does (the look-ahead and the acceleration are the plan's)
        cap = np.asarray(sp.cap_mm_s, float)
        speed = np.where(~exact & np.isfinite(cap) & (cap >= peak * (1.0 - 1e-9)), cap, speed)
    return np.where(ok, speed, np.nan)


def stretch_accel(a_mm_s2: float) -> float:
    """The acceleration a slowed stretch's line gives the firmware for the plan's ``a_mm_s2``:
    rounded down (the firmware never accelerates harder than planned), to whole mm/s², below 1
    mm/s² to 0.001 (the least a firmware line takes, gcode.reader). A cell of a move sliced at
    100 mm/s² slowed to a twentieth of its speed plans 0.25 mm/s²; rounded down to whole units,
    such a cell wrote ``M204 P0``, which no firmware runs (the output's check refused the file)."""
    if a_mm_s2 >= 1.0:
        return float(math.floor(a_mm_s2))
    return max(math.floor(a_mm_s2 * 1000.0) / 1000.0, 1e-3)


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
        key = None if r >= SCALE_OVERRIDE_BELOW else (stretch_accel(float(cells.accel_mm_s2[c])), r)
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
