"""The firmware's planner blocks of a program: straight pieces in XYZ+E with the limits in
force (replay.Replay), as arrays; G2/G3 cut into the firmware's chords.

Both firmwares: exact stops at E-only moves, dwells (G4), waits (M400, M109, ...), homing and
tool changes; firmware retraction (G10/G11) takes retract_mm/retract_speed. Settings found in
the file apply from that line on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .base import norm3


@dataclass(frozen=True)
class Blocks:
    """The firmware's planner blocks (N): straight pieces in XYZ+E.

    start_mm (N,3), end_mm (N,3), e0_mm (N,), de_mm (N,), length_mm (N,) (XYZ length, or |ΔE|
    for E-only blocks; Klipper: |ΔE| × M221), accel (N,), peak_accel (N,) (Klipper: the
    pseudo-accel of minimum_cruise_ratio; Marlin: accel), vcap (N,), stop_after (N,),
    dwell_after_s (N,), lead_s; ``jd`` (N,) the junction deviation of each block (Klipper: from
    square_corner_velocity and the toolhead's accel), ``turn_cos`` (N-1,) per junction;
    ``firmware`` the variant (firmware.base.Firmware) whose rules plan them."""

    start_mm: np.ndarray
    end_mm: np.ndarray
    e0_mm: np.ndarray
    de_mm: np.ndarray
    length_mm: np.ndarray
    accel: np.ndarray
    peak_accel: np.ndarray
    vcap: np.ndarray
    stop_after: np.ndarray
    dwell_after_s: np.ndarray
    jd: np.ndarray
    turn_cos: np.ndarray
    lead_s: float
    firmware: object
    #: (N-1,) classic-jerk junction limit (inf where junction deviation applies)
    jerk_v: np.ndarray | None = None
    #: Klipper: (N,) the extruder's share of each block, dE/L (dE × M221), whose change at a
    #: junction is held to ``icv_mm_s`` (instantaneous_corner_velocity); None for Marlin
    e_ratio: np.ndarray | None = None
    icv_mm_s: float = 1.0

    def plan(self):
        """The trapezoids the firmware plans for these blocks."""
        return self.firmware.plan_blocks(self)


def arc_points(mv, nseg: int) -> list:
    """The chord end points of an arc move cut into ``nseg`` chords (the start first, the
    move's own end last)."""
    arc = mv.arc
    pts = [np.asarray(mv.start_mm, float)]
    th0 = math.atan2(mv.start_mm[1] - arc.center_mm[1], mv.start_mm[0] - arc.center_mm[0])
    for j in range(1, nseg + 1):
        u = j / nseg
        th = th0 + arc.sweep_rad * u
        pts.append(np.array([arc.center_mm[0] + arc.radius_mm * math.cos(th),
                             arc.center_mm[1] + arc.radius_mm * math.sin(th),
                             mv.start_mm[2] + (mv.end_mm[2] - mv.start_mm[2]) * u]))
    pts[-1] = np.asarray(mv.end_mm, float)
    return pts


def arc_rows(mv, lim, fw, firmware, feed: float):
    """The chords of one arc move as block rows (start, end, e0, de, L, accel, peak accel,
    speed cap, jd, E-only, jerk, e ratio), or None where the arc is too short to move (never
    for real arcs; it is then a still move: E-only or nothing)."""
    arc = mv.arc
    planar = abs(arc.sweep_rad) * arc.radius_mm
    nseg = firmware.arc_segments(planar, mv.end_mm[2] - mv.start_mm[2], fw)
    pts = arc_points(mv, nseg)
    total = sum(norm3(pts[j + 1] - pts[j]) for j in range(len(pts) - 1))
    if total <= 1e-9:
        return None
    de_total = mv.de_mm
    e0 = mv.e_start_mm
    base_a = lim.accel_print if de_total > 0 else lim.accel_travel
    rows = []
    for j in range(len(pts) - 1):
        d = pts[j + 1] - pts[j]
        L = norm3(d)
        if L <= 1e-12:
            continue
        de = de_total * L / total
        rows.append(firmware.chord_row(lim, pts[j], pts[j + 1], d, L, de, e0, feed, base_a))
        e0 += de
    return rows


def _empty(lead: float, firmware) -> Blocks:
    z = np.zeros(0)
    return Blocks(np.zeros((0, 3)), np.zeros((0, 3)), z, z, z, z, z, z, np.zeros(0, bool), z,
                  z, z, lead, firmware)


def build_blocks(replay) -> Blocks:
    """Split the replay's program into the firmware's planner blocks with the limits in force.

    Long for a reason: one pass of array steps whose order the bit-identity tests pin. The
    limits in force are taken once per event (the replay's snapshots) and looked up per move;
    a straight move is one block whose length, caps and accelerations are computed
    element-wise with the move-by-move reference's operations in the same order (the length
    as √((dx² + dy²) + dz²), base.norm3), so the blocks are bit-identical
    (tests/firmware/reference.py). Arcs (rare: chords) go row by row. A replay with an
    override (firmware.accel_override) gives the program as if each file line lowering an
    acceleration were followed by the writer's line raising it."""
    program, fwv = replay.program, replay.firmware
    fw = replay.profile.firmware
    moves = program.moves
    events = program.events
    m = len(moves)
    snaps, si = replay.snaps, replay.si
    macc = np.array([[q.max_accel[k] for k in "xyze"] for q in snaps])[si]
    mfeed = np.array([[q.max_feed[k] for k in "xyze"] for q in snaps])[si]
    start = np.array([mv.start_mm for mv in moves], dtype=float).reshape(m, 3)
    end = np.array([mv.end_mm for mv in moves], dtype=float).reshape(m, 3)
    e_start = np.array([mv.e_start_mm for mv in moves], dtype=float)
    de_total = np.array([mv.e_end_mm for mv in moves], dtype=float) - e_start
    feed = np.array([mv.feed_mm_s for mv in moves], dtype=float)
    is_arc = np.array([mv.arc is not None for mv in moves], dtype=bool)
    d = end - start
    total = np.sqrt((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2])
    still = total <= 1e-9
    # chords of the arcs, row by row; an arc too short to move is a still move
    rows_of_arc = {}
    for mi in np.flatnonzero(is_arc):
        rows = arc_rows(moves[mi], snaps[si[mi]], fw, fwv, float(feed[mi]))
        if rows is None:
            is_arc[mi], still[mi] = False, True
        else:
            rows_of_arc[int(mi)] = rows
    eonly = ~is_arc & still & (np.abs(de_total) > 1e-12)
    line = ~is_arc & ~still
    count = (line | eonly).astype(np.int64)
    for mi, rows in rows_of_arc.items():
        count[mi] = len(rows)
    rows_before = np.concatenate([[0], np.cumsum(count)])
    n = int(rows_before[-1])
    lead = 0.0
    if n == 0:
        for ev in events:
            if ev.stop:
                lead += ev.dwell_s
        return _empty(lead, fwv)
    b_start = np.empty((n, 3))
    b_end = np.empty((n, 3))
    b_e0 = np.empty(n)
    out = {"de": np.empty(n), "L": np.empty(n), "acc": np.empty(n), "peak": np.empty(n),
           "vcap": np.empty(n), "jd": np.empty(n),
           "jerk": np.full((n, 3), np.nan),  # NaN: junction deviation applies at this block
           "er": np.zeros(n)}
    b_eonly = np.zeros(n, bool)

    # straight moves: one block each; E-only moves: one block each, a stop on both sides
    li = np.flatnonzero(line)
    ei_ = np.flatnonzero(eonly)
    for idx in (li, ei_):
        r = rows_before[idx]
        b_start[r] = start[idx]
        b_e0[r] = e_start[idx]
    b_end[rows_before[li]] = end[li]
    b_end[rows_before[ei_]] = start[ei_]
    b_eonly[rows_before[ei_]] = True
    fwv.straight_blocks(snaps, si, li, ei_, rows_before[li], rows_before[ei_], d[li], total[li],
                        de_total, feed, macc, mfeed, out)

    for mi, rows in rows_of_arc.items():
        r0 = int(rows_before[mi])
        for j, row in enumerate(rows):
            b_start[r0 + j], b_end[r0 + j] = row[0], row[1]
            b_e0[r0 + j], out["de"][r0 + j], out["L"][r0 + j] = row[2], row[3], row[4]
            (out["acc"][r0 + j], out["peak"][r0 + j], out["vcap"][r0 + j],
             out["jd"][r0 + j]) = row[5:9]
            out["er"][r0 + j] = row[11]
            if row[10] is not None:
                out["jerk"][r0 + j] = [row[10][k] for k in "xyz"]

    # stops, in file order as the reference meets them: an event stops after the last block
    # before its move (or adds to the lead-in); an E-only block stops the block before it
    stop_after = np.zeros(n, bool)
    dwell = np.zeros(n)
    for ev in events:
        if ev.stop:
            k = int(rows_before[ev.move_index]) - 1
            if k >= 0:
                stop_after[k] = True
                dwell[k] = dwell[k] + ev.dwell_s
            else:
                lead += ev.dwell_s
    r = rows_before[ei_]
    stop_after[r[r > 0] - 1] = True
    stop_after[-1] = True
    stop_after |= b_eonly
    turn, jerk_v = junction_geometry(b_start, b_end, b_eonly, out["jerk"])
    return Blocks(b_start, b_end, b_e0, out["de"], out["L"], out["acc"], out["peak"],
                  out["vcap"], stop_after, dwell, out["jd"], turn, lead, fwv, jerk_v,
                  fwv.block_e_ratio(out["er"]), fw.instantaneous_corner_velocity_mm_s)


def junction_geometry(b_start, b_end, b_eonly, b_jerk):
    """(turn_cos (N-1,), jerk_v (N-1,)): the cosine of each junction's turn (a reversal next
    to an E-only block, so no speed carries) and, where the next block has classic jerk, the
    highest speed at which no axis changes by more than its jerk (inf elsewhere)."""
    d = b_end - b_start
    nrm = np.linalg.norm(d, axis=1, keepdims=True)
    unit = np.where(nrm > 0, d / np.where(nrm > 0, nrm, 1), 0.0)
    turn = np.einsum("ij,ij->i", unit[:-1], unit[1:])
    turn = np.where(b_eonly[:-1] | b_eonly[1:], -1.0, turn)
    dv = np.abs(unit[1:] - unit[:-1])
    with np.errstate(divide="ignore", invalid="ignore"):
        jv = np.where(dv > 1e-12, b_jerk[1:] / dv, np.inf).min(axis=1)
    jerk_v = np.where(np.isnan(b_jerk[1:, 0]), np.inf, jv)
    return turn, jerk_v
