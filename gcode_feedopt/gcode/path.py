"""The parametric path: exact lines and arcs along arc length ``s_mm``.

Only moves that travel in XYZ become segments. E-only moves (retract/unretract), dwells,
waits, homing and tool changes become *stops* at the end of the preceding segment, with the
time the machine stands still there (``dwell_after_s``). Arcs stay arcs: position, tangent
and curvature are evaluated exactly (helical Z linear in the sweep).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .reader import EXTRUDE, RETRACT, TRAVEL, UNRETRACT, ZHOP, E_ONLY, Program

SEG_LINE, SEG_ARC_CW, SEG_ARC_CCW = 0, 1, 2
KIND_CODES = {EXTRUDE: 0, TRAVEL: 1, RETRACT: 2, UNRETRACT: 3, ZHOP: 4, E_ONLY: 5}

#: Segments shorter than this are merged into a stop-free no-op (mm): below a step of any
#: printer (an Ender 3 has 80 steps/mm, 12.5 µm per step).
MIN_SEGMENT_MM = 1e-6


@dataclass(frozen=True)
class Path:
    """Piecewise path of N segments in machine coordinates.

    Attributes (arrays, N = number of segments):
        start_mm, end_mm: (N, 3) segment end points, mm.
        kind: (N,) int8, SEG_LINE / SEG_ARC_CW / SEG_ARC_CCW.
        center_mm: (N, 2) arc centre (NaN for lines), mm.
        radius_mm: (N,) arc radius (0 for lines), mm.
        theta0_rad: (N,) arc start angle, rad.
        sweep_rad: (N,) signed arc sweep (+CCW), rad.
        length_mm: (N,) XYZ length (helix length for arcs), mm.
        s0_mm: (N+1,) cumulative length; segment i spans [s0[i], s0[i+1]].
        de_mm: (N,) filament fed over the segment, mm.
        move_kind: (N,) int8 codes of KIND_CODES.
        layer: (N,) int32.
        move_index: (N,) index into Program.moves.
        feed_mm_s: (N,) the slicer's feed for the move, mm/s.
        fixed: (N,) bool, the writer must leave the line as it is (numbered lines).
        stop_after: (N,) bool, the machine must stand still at the end of segment i.
        dwell_after_s: (N,) time it stands still there, s.
        dwell_before_s: float, time stood still before the first segment, s.
    """

    start_mm: np.ndarray
    end_mm: np.ndarray
    kind: np.ndarray
    center_mm: np.ndarray
    radius_mm: np.ndarray
    theta0_rad: np.ndarray
    sweep_rad: np.ndarray
    length_mm: np.ndarray
    s0_mm: np.ndarray
    de_mm: np.ndarray
    move_kind: np.ndarray
    layer: np.ndarray
    move_index: np.ndarray
    feed_mm_s: np.ndarray
    fixed: np.ndarray
    stop_after: np.ndarray
    dwell_after_s: np.ndarray
    dwell_before_s: float = 0.0

    @property
    def n_segments(self) -> int:
        return int(self.length_mm.size)

    @property
    def total_length_mm(self) -> float:
        return float(self.s0_mm[-1])

    def segment_at(self, s_mm: np.ndarray) -> np.ndarray:
        """(M,) index of the segment holding each s (the later one at a boundary, the last
        segment at the end)."""
        idx = np.searchsorted(self.s0_mm, np.asarray(s_mm, dtype=float), side="right") - 1
        return np.clip(idx, 0, self.n_segments - 1)

    def _local(self, s_mm):
        s = np.asarray(s_mm, dtype=float)
        i = self.segment_at(s)
        L = self.length_mm[i]
        u = np.where(L > 0, (s - self.s0_mm[i]) / np.where(L > 0, L, 1.0), 0.0)
        return i, np.clip(u, 0.0, 1.0)

    def position(self, s_mm) -> np.ndarray:
        """(M, 3) position at arc length s, mm."""
        i, u = self._local(s_mm)
        p = self.start_mm[i] + (self.end_mm[i] - self.start_mm[i]) * u[:, None]
        arc = self.kind[i] != SEG_LINE
        if np.any(arc):
            ia = i[arc]
            th = self.theta0_rad[ia] + self.sweep_rad[ia] * u[arc]
            r = self.radius_mm[ia]
            p[arc, 0] = self.center_mm[ia, 0] + r * np.cos(th)
            p[arc, 1] = self.center_mm[ia, 1] + r * np.sin(th)
        return p

    def tangent(self, s_mm) -> np.ndarray:
        """(M, 3) unit tangent at arc length s."""
        i, u = self._local(s_mm)
        d = self.end_mm[i] - self.start_mm[i]
        arc = self.kind[i] != SEG_LINE
        if np.any(arc):
            ia = i[arc]
            th = self.theta0_rad[ia] + self.sweep_rad[ia] * u[arc]
            r = self.radius_mm[ia]
            sw = self.sweep_rad[ia]
            d[arc, 0] = -r * np.sin(th) * sw
            d[arc, 1] = r * np.cos(th) * sw
        n = np.linalg.norm(d, axis=1, keepdims=True)
        return d / np.where(n > 0, n, 1.0)

    def curvature(self, s_mm) -> np.ndarray:
        """(M,) curvature 1/R of the XY projection (0 on lines), 1/mm."""
        i, _ = self._local(s_mm)
        r = self.radius_mm[i]
        return np.where(self.kind[i] != SEG_LINE, 1.0 / np.where(r > 0, r, np.inf), 0.0)

    def end_tangents(self) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) unit tangents at the start and at the end of every segment (evaluated at
        u = 0 and u = 1 of each segment, never stepping into a neighbour)."""
        d = self.end_mm - self.start_mm
        arc = self.kind != SEG_LINE
        t_end = d.copy()
        t_beg = d.copy()
        if np.any(arc):
            th1 = self.theta0_rad[arc] + self.sweep_rad[arc]
            th0 = self.theta0_rad[arc]
            r = self.radius_mm[arc]
            sw = self.sweep_rad[arc]
            dz = d[arc, 2]
            t_end[arc] = np.stack([-r * np.sin(th1) * sw, r * np.cos(th1) * sw, dz], axis=1)
            t_beg[arc] = np.stack([-r * np.sin(th0) * sw, r * np.cos(th0) * sw, dz], axis=1)

        def unit(v):
            n = np.linalg.norm(v, axis=1, keepdims=True)
            return v / np.where(n > 0, n, 1.0)

        return unit(t_beg), unit(t_end)

    def junction_cos(self) -> np.ndarray:
        """(N-1,) cosine of the angle between the end tangent of segment i and the start
        tangent of segment i+1 (1 = straight on, -1 = full reversal)."""
        t_beg, t_end = self.end_tangents()
        return np.einsum("ij,ij->i", t_end[:-1], t_beg[1:])


def build_path(program: Program, *, e_feed_cap_mm_s=25.0, e_accel_mm_s2=5000.0,
               e_scale=1.0) -> Path:
    """Turn a Program into a Path.

    Args:
        program: the parsed file.
        e_feed_cap_mm_s: the firmware's maximum extruder speed, one for the file or (M,) one per
            move (firmware.MoveLimits.e_feed_mm_s); an E-only move runs at the lower of its F
            and this.
        e_accel_mm_s2: the acceleration of E-only moves, one or (M,) per move
            (MoveLimits.e_accel_mm_s2), used for their duration.
        e_scale: one or (M,) factor on the E of E-only moves for their duration (Klipper's
            M221 scales E; MoveLimits.extrude_factor).
    """
    moves = program.moves
    seg_moves, stop_after, dwell_after, dwell_before = _segments_and_stops(
        program, e_feed_cap_mm_s, e_accel_mm_s2, e_scale)
    n = len(seg_moves)
    seg = [moves[mi] for mi in seg_moves]
    # one list per field, then one array each (row-by-row assignment costs more than the rest
    # of the function)
    start = np.array([mv.start_mm for mv in seg], dtype=float).reshape(n, 3)
    end = np.array([mv.end_mm for mv in seg], dtype=float).reshape(n, 3)
    kind = np.zeros(n, dtype=np.int8)
    center = np.full((n, 2), np.nan)
    radius = np.zeros(n)
    theta0 = np.zeros(n)
    sweep = np.zeros(n)
    length = np.array([mv.xyz_length_mm for mv in seg], dtype=float)
    de = np.array([mv.de_mm for mv in seg], dtype=float)
    mkind = np.array([KIND_CODES[mv.kind] for mv in seg], dtype=np.int8)
    layer = np.array([mv.layer for mv in seg], dtype=np.int32)
    feed = np.array([mv.feed_mm_s for mv in seg], dtype=float)
    fixed = np.array([mv.fixed for mv in seg], dtype=bool)
    for k, mv in enumerate(seg):
        if mv.arc is not None:
            kind[k] = SEG_ARC_CW if mv.arc.cw else SEG_ARC_CCW
            center[k] = mv.arc.center_mm
            radius[k] = mv.arc.radius_mm
            theta0[k] = np.arctan2(mv.start_mm[1] - mv.arc.center_mm[1],
                                   mv.start_mm[0] - mv.arc.center_mm[0])
            sweep[k] = mv.arc.sweep_rad
    s0 = np.concatenate([[0.0], np.cumsum(length)])
    stop = np.zeros(n, dtype=bool)
    dwell = np.zeros(n)
    for k in stop_after:
        stop[k] = True
        dwell[k] = dwell_after.get(k, 0.0)
    if n:
        stop[-1] = True
    return Path(start_mm=start, end_mm=end, kind=kind, center_mm=center, radius_mm=radius,
                theta0_rad=theta0, sweep_rad=sweep, length_mm=length, s0_mm=s0, de_mm=de,
                move_kind=mkind, layer=layer, move_index=np.asarray(seg_moves, dtype=np.int64),
                feed_mm_s=feed, fixed=fixed, stop_after=stop, dwell_after_s=dwell,
                dwell_before_s=float(dwell_before))


def _segments_and_stops(program: Program, e_feed_cap_mm_s, e_accel_mm_s2, e_scale):
    """(indices of the moves that travel in XYZ, {segment: stop after it}, {segment: dwell
    after it, s}, dwell before the first segment, s): an E-only move is a stop lasting what
    the firmware gives it (a rest-to-rest trapezoid at its caps), an event with a stop (a
    dwell, a homing) a stop of its dwell (build_path's arguments)."""
    moves = program.moves
    e_caps = np.broadcast_to(np.asarray(e_feed_cap_mm_s, float), (len(moves),))
    e_accs = np.broadcast_to(np.asarray(e_accel_mm_s2, float), (len(moves),))
    e_scales = np.broadcast_to(np.asarray(e_scale, float), (len(moves),))
    seg_moves = []
    dwell_after: dict[int, float] = {}
    stop_after: set[int] = set()
    dwell_before = 0.0

    def add_stop(dwell: float):
        nonlocal dwell_before
        if seg_moves:
            k = len(seg_moves) - 1
            stop_after.add(k)
            dwell_after[k] = dwell_after.get(k, 0.0) + dwell
        else:
            dwell_before += dwell

    def e_move_time(de: float, feed: float, mi: int) -> float:
        cap, acc = float(e_caps[mi]), float(e_accs[mi])
        v = min(feed, cap) if feed > 0 else cap
        d = abs(de) * float(e_scales[mi])
        # trapezoid from rest to rest
        if d * acc >= v * v:
            return d / v + v / acc
        return 2.0 * np.sqrt(d / acc)

    ev_iter = iter(program.events)
    ev = next(ev_iter, None)
    for mi, mv in enumerate(moves):
        while ev is not None and ev.move_index <= mi:
            if ev.stop:
                add_stop(ev.dwell_s)
            ev = next(ev_iter, None)
        if mv.xyz_length_mm <= MIN_SEGMENT_MM:
            if abs(mv.de_mm) > 0:
                add_stop(e_move_time(mv.de_mm, mv.feed_mm_s, mi))
            continue
        seg_moves.append(mi)
    while ev is not None:
        if ev.stop:
            add_stop(ev.dwell_s)
        ev = next(ev_iter, None)
    return seg_moves, stop_after, dwell_after, dwell_before
