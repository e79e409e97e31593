"""The slow-down's planning grid: the path cut into cells of at most ``grid_mm``, grouped into
pieces between exact stops, and the firmware's own look-ahead on their scaled limits (steps 1
and 2 of the slow-down, optimize.slowdown)."""

from __future__ import annotations

import numpy as np

from ...firmware import by_flavour
from ...plan.kinematic import PlannerLimits
from ..free import ranges


class PlanGrid:
    """The path cut into planning cells, grouped into pieces between exact stops.

    Attributes:
        parent: (M,) segment of each cell.
        length_mm, s0_mm: (M,), (M+1,) cell lengths and start positions (s0 at every segment
            start is the path's own, exactly).
        vcap_mm_s, accel_mm_s2: (M,) F's limits of each cell.
        junction_mm_s: (M+1,) F's junction limits (inf between the cells of one segment).
        jerk_junction: (M+1,) bool, junctions F's classic jerk sets.
        pseudo_accel_mm_s2: (M,) Klipper: minimum_cruise_ratio's pseudo-accel of each cell
            (its move's), or None (Marlin).
        flavour: the firmware variant whose look-ahead plans the cells.
        fixed: (M,) bool, cells of lines the writer must keep (never scaled).
        piece_cell: (P+1,) first cell of each piece (pieces end at exact stops).
        piece_hold: (P,) samples held at rest after each piece (its dwell).
        lead_hold: samples held at rest before the first piece.
    """

    def __init__(self, path, limits: PlannerLimits, grid_mm: float, ts_s: float):
        L = np.asarray(path.length_mm, float)
        nsub = np.maximum(1, np.ceil(L / grid_mm - 1e-9)).astype(np.int64)
        self.parent = np.repeat(np.arange(L.size), nsub)
        first = np.concatenate([[0], np.cumsum(nsub)])
        k_in = np.arange(self.parent.size) - first[self.parent]
        s0 = path.s0_mm[self.parent] + L[self.parent] * k_in / nsub[self.parent]
        self.s0_mm = np.concatenate([s0, [path.s0_mm[-1]]])
        self.s0_mm[first] = path.s0_mm  # exact at segment boundaries
        self.length_mm = np.diff(self.s0_mm)
        self.vcap_mm_s = limits.vcap_mm_s[self.parent]
        self.accel_mm_s2 = limits.accel_mm_s2[self.parent]
        vj = np.full(self.parent.size + 1, np.inf)
        vj[first] = limits.junction_mm_s
        self.junction_mm_s = vj
        jerk = np.zeros(self.parent.size + 1, bool)
        if limits.jerk_junction is not None:
            jerk[first] = limits.jerk_junction
        self.jerk_junction = jerk
        pa = limits.pseudo_accel_mm_s2
        self.pseudo_accel_mm_s2 = None if pa is None else np.asarray(pa, float)[self.parent]
        self.flavour = limits.flavour
        self.fixed = np.asarray(path.fixed, bool)[self.parent]
        stop = np.asarray(path.stop_after, bool) | (np.asarray(path.dwell_after_s) > 0)
        stop[-1] = True
        self.piece_cell = np.concatenate([[0], first[1:][stop]])
        self.piece_hold = np.rint(np.asarray(path.dwell_after_s)[stop] / ts_s).astype(np.int64)
        self.lead_hold = int(round(path.dwell_before_s / ts_s))
        self.ts_s = float(ts_s)

    @property
    def n_cells(self) -> int:
        return int(self.parent.size)

    @property
    def n_pieces(self) -> int:
        return int(self.piece_cell.size - 1)

    def piece_of_cell(self) -> np.ndarray:
        return np.repeat(np.arange(self.n_pieces), np.diff(self.piece_cell))

    def plan(self, scale: np.ndarray, pieces: np.ndarray):
        """Plan ``pieces`` (sorted piece indices) under the scaled limits.

        Returns per piece (lists in the order of ``pieces``): motion samples s (K_p,) at
        t = Ts, 2Ts, … from the piece's start at rest (the last one at its end), the local
        motion start and end time of each of its cells (s), and each cell's entry speed
        (mm/s; with the times it tells which cells a change of scale moved)."""
        pieces = np.asarray(pieces, np.int64)
        if pieces.size == 0:
            return [], [], [], []
        ca, cb = self.piece_cell[pieces], self.piece_cell[pieces + 1]
        _, cells = ranges(ca, cb)
        n_c = cb - ca
        first_c = np.concatenate([[0], np.cumsum(n_c)[:-1]])
        r = scale[cells]
        L = self.length_mm[cells]
        vc = self.vcap_mm_s[cells] * r
        acc = self.accel_mm_s2[cells] * r * r
        # junctions: F's limit times the smaller scale of the two sides (junction deviation,
        # Klipper's square corner and centripetal rules take the smaller acceleration of the
        # two moves), or the scale of the cell after it where classic jerk sets it (the
        # firmware takes the jerk in force for the move it plans: the writer's M205 line for
        # that cell), within both caps; the first junction of every piece is a stop (or the
        # path's start): 0
        m = cells.size
        vj = np.zeros(m + 1)
        inner = np.ones(m, bool)
        inner[first_c] = False
        j = np.flatnonzero(inner)
        rj = np.where(self.jerk_junction[cells[j]], r[j], np.minimum(r[j - 1], r[j]))
        vj[j] = np.minimum(self.junction_mm_s[cells[j]] * rj, np.minimum(vc[j - 1], vc[j]))
        # the firmware's own look-ahead. Klipper: a slowed cell's ACCEL is r²·a, so its
        # pseudo-accel a·(1 − mcr) scales alike; cells of one move reproduce the move's reduced
        # peak (their junctions are unlimited), so the grid plans what Klipper runs
        pseudo = (None if self.pseudo_accel_mm_s2 is None
                  else self.pseudo_accel_mm_s2[cells] * r * r)
        tr = by_flavour(self.flavour).lookahead(vj, L, acc, pseudo, vc, np.zeros(m), 0.0)
        motion = tr.motion_s
        # local times: restart the clock at every piece
        piece_of = np.repeat(np.arange(pieces.size), n_c)
        t_end_glob = np.cumsum(motion)
        t_start_glob = t_end_glob - motion
        t_start = t_start_glob - t_start_glob[first_c][piece_of]
        t_end = t_end_glob - t_start_glob[first_c][piece_of]
        dur = np.add.reduceat(motion, first_c)
        k_p = np.maximum(1, np.ceil(dur / self.ts_s - 1e-9)).astype(np.int64)
        # sample every piece at once on a virtual clock that separates the pieces by 1 s
        gap = np.concatenate([[0.0], np.cumsum(dur + 1.0)[:-1]])
        owner, kk = ranges(np.ones(pieces.size, np.int64), k_p + 1)
        t_loc = kk * self.ts_s
        i = np.searchsorted(t_start + gap[piece_of], t_loc + gap[owner], side="right") - 1
        i = np.clip(i, first_c[owner], first_c[owner] + n_c[owner] - 1)
        tau = t_loc - t_start[i]
        v0, a, vcc = tr.v0_mm_s[i], tr.accel_mm_s2[i], tr.vc_mm_s[i]
        ta, tc, td = tr.t_acc_s[i], tr.t_cru_s[i], tr.t_dec_s[i]
        t3 = tau - ta - tc
        s_loc = np.where(tau < ta, v0 * tau + 0.5 * a * tau * tau,
                         np.where(tau < ta + tc, tr.d_acc_mm[i] + vcc * (tau - ta),
                                  np.where(tau < ta + tc + td,
                                           tr.d_acc_mm[i] + tr.d_cru_mm[i] + vcc * t3
                                           - 0.5 * a * t3 * t3, L[i])))
        end_s = self.s0_mm[cb]
        s = np.minimum(self.s0_mm[cells][i] + np.clip(s_loc, 0.0, L[i]), end_s[owner])
        s[np.cumsum(k_p) - 1] = end_s  # the last sample of every piece is at its end, exactly
        s = np.maximum.accumulate(s)
        cut_s, cut_c = np.cumsum(k_p)[:-1], np.cumsum(n_c)[:-1]
        return (np.split(s, cut_s), np.split(t_start, cut_c), np.split(t_end, cut_c),
                np.split(tr.v0_mm_s, cut_c))

