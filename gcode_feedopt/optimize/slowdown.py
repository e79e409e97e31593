"""Whole-file twin-driven planning: local slow-down of the firmware's own plan (issue 9).

The receding-window LP (mpc.py, paper Sec. 4) solves a sequential LP every 60 ms of motion
wherever the twin predicts the firmware's plan F breaks the tolerance. On a Benchy that is a
quarter of all windows (half of all horizons see a violation): minutes of LP solves. This
module finds a plan of the same quality with whole-file vectorized passes instead:

1. **Grid.** Every segment is cut into cells of at most ``grid_mm`` (planning only: cells of
   one move meet straight on, so no junction rule applies between them). Each cell c has a
   scale r_c ∈ (0, 1]: its feed cap becomes r·v_cap, its acceleration r²·a, and the junction
   speeds at its ends r·v_j (the smaller r of the two sides; under classic jerk the r of the
   cell after the junction, as the firmware plans it). That is a *local time dilation*: the same path at 1/r of the
   speed, whose dynamic errors (∝ acceleration) shrink as r². With r = 1 everywhere the plan
   is F exactly; with r < 1 it is what the firmware plans once the writer tells it the cell's
   acceleration and junction rule (gcode.writer: M204/M205, SET_VELOCITY_LIMIT), so the
   written file runs as planned.
2. **Plan.** The firmware's own look-ahead (plan.trapezoid.forward_backward and trapezoids)
   on the scaled limits, per piece between exact stops (each starts and ends at rest and is
   sampled from its own start, as the window optimizer commits whole samples); the schedule
   is the concatenation of the pieces with their dwells.
3. **Verify.** The twin predicts the plan (predictors.predict_trajectory, vectorized): the
   chance bound |μ_ε| + Φ⁻¹(η)σ_ε (Eq. 27, both signs) on extruding samples, and the
   overshoot half-planes at near-reversals (free.ContourRules), exactly as the window
   optimizer verifies its plans.
4. **Slow down** where the bound exceeds E_max: every cell in motion during the cause window
   [t − ``cause_before_s``, t + ``cause_after_s``] of a violating sample t is scaled by
   ((aim·E_max − zσ)/|μ|)^``exponent`` clipped to ``step`` (the error part that speed
   changes, against the room the uncertainty leaves), the smallest factor where windows
   overlap. A violation that survives ``escalate_after`` rounds (its cause lies outside the
   window) gets a wider window and a firmer step. Repeat until no sample violates.
5. **Grow back.** Slowing whole cause windows over-corrects; every slowed cell is sped up by
   each factor of ``grow`` in turn, cells in the cause window of a sample the trial breaks
   keep their speed, and step 4 settles what remains.

Only what changed is predicted again. A cell whose motion did not change moves as before,
only later by the delay of the changed cells before it, so its samples keep their old values
(time-shifted to the nearest sample); samples in changed cells and ``round_history_s`` after
them are predicted, each stretch with ``round_history_s`` of history from its own first
command (within 0.3 µm of the whole-file prediction on a Benchy). Those values are
provisional: the whole-file checks at the end (``max_checks``) predict every provisional
sample again with the twin's whole memory (n_taps + max(n2, n3) samples) before it, which is
the whole-file prediction exactly (tested), and settle any violation that reveals. The
returned plan and its bound are exact.

Long files are split into contiguous groups of pieces planned in forked worker processes,
each starting from F's history (the twin is time-invariant: only its memory before a group
matters); the parent takes the groups' plans as they are, predicts again the samples right
after each group boundary (which remember the other group's plan, not F), and settles there.

Samples predicted over the tolerance even at rest (the oracle's plant carries a disturbance
larger than the tolerance leaves room for, or the twin's noise level alone fills it), or even
with their whole cause window at the ``scale_min`` floor after looking back up to
``max_cause_before_s`` (a hard stop into a slowed stretch rings on through it: the cause is
the stop, before the window), are given up on, counted in ``info["relaxed_samples"]``, and
their cells return to full speed (slowing them down does not help). The twin's uncertainty is
mostly the motion's own (the spread of the FRFs acts on the command's deviations), so a step's
factor counts only the uncertainty at rest as fixed and scales the rest with the motion.

The plan stays within F everywhere (every limit is F's limit times r ≤ 1); ``cells`` of the
result tell the writer where and how much it was slowed.
"""

from __future__ import annotations

import multiprocessing as mp
import time
from dataclasses import dataclass

import numpy as np

from ..gcode.schedule import SlowdownCells
from ..plan.kinematic import PlannerLimits
from ..procs import worker_pool
from ..plan.trapezoid import forward_backward, peak_speed, trapezoids
from ..vm.metrics import CONTOUR_WINDOW_S, distance_to_polyline_window
from ..vm.plant import simulate_axes
from . import parallel
from .free import ranges
from .mpc import _normals
from .predictors import predict_trajectory


@dataclass(frozen=True)
class SlowdownSettings:
    """Knobs of the slow-down optimizer (chosen against the window optimizer on excerpts of
    four real files and the butterfly: docs/optimizer.md)."""

    #: longest planning cell, mm (≈ 20 ms at 70 mm/s: finer than any cause window)
    grid_mm: float = 1.5
    #: a violation at t is caused by the motion in [t − before, t + after], s (measured: 10–15
    #: ms plans fastest; the contour error lags the command by a few ms)
    cause_before_s: float = 0.015
    cause_after_s: float = 0.004
    #: speed factor per step = (room / error)^exponent: dynamic errors grow between v (a
    #: corner's velocity step) and v² (acceleration); the cautious 0.5 over-slows least
    exponent: float = 0.5
    #: smallest and largest factor of one step
    step: tuple[float, float] = (0.6, 0.95)
    #: the factor aims at this fraction of E_max, so sampling does not make it oscillate
    aim: float = 0.98
    #: grow-back factors, tried in turn (a third pass, 1.04, gains ~0.2 % of cycle time for
    #: ~15 % more work on a Benchy)
    grow: tuple[float, ...] = (1.25, 1.08)
    #: slow-down rounds per settle
    max_rounds: int = 40
    #: after this many rounds of one settle the remaining violations (few) get a cause window
    #: twice as wide every two rounds and a firmer step
    escalate_after: int = 4
    #: floor of the scale: below it a violation is not motion-induced
    scale_min: float = 0.05
    #: a violation whose cause window is all at the floor looks back up to this far (the
    #: window doubling) before it is given up on, s: the ringing after a hard stop into a
    #: slowed stretch decays as e^(−ζωt), ~65 ms for a 37 Hz mode at ζ 0.067
    max_cause_before_s: float = 0.5
    #: whole-file checks at the end (each may reveal violations that rounds settle)
    max_checks: int = 4
    #: during rounds a changed stretch is predicted with this much history before it (and
    #: after it), each window from its own first command: within 0.3 µm of the whole-file
    #: prediction on a Benchy (measured), and 3.6× less work than the twin's whole memory;
    #: the whole-file checks predict those samples again with the whole memory, s
    round_history_s: float = 0.3
    #: worker processes (None: optimize.parallel.default_workers()); files with fewer samples
    #: of F than ``min_parallel_samples`` are planned in one process
    workers: int | None = None
    min_parallel_samples: int = 200_000
    #: samples of F per worker group at most: a group's rounds cost its own length each
    #: (whole-group passes), so bounded groups keep the cost linear in the file's length
    group_samples: int = 200_000


@dataclass
class SlowdownResult:
    """What :func:`plan_slowdown` returns.

    Attributes:
        s_mm: (K,) path position at t_k = k·Ts, mm.
        scale: (M,) final scale of every grid cell.
        info: rounds, evaluations, samples evaluated, relaxed samples, compute seconds,
            fraction of length slowed, workers.
        mean_xy_mm, bound_mm: (K, 2), (K,) the twin's prediction of the final plan and its
            chance bound (0 on unconstrained samples), mm.
        motion_mm: (K,) the part of the bound the motion causes (|μ_ε| or the overshoot
            excursion; the rest is Φ⁻¹(η)σ_ε), mm.
        cells: the grid for the writer (gcode.schedule.SlowdownCells: cell boundaries,
            segment, scale, the plan's acceleration, feed cap and peak speed of each cell, and
            F's classic-jerk junctions).
    """

    s_mm: np.ndarray
    scale: np.ndarray
    info: dict
    mean_xy_mm: np.ndarray
    bound_mm: np.ndarray
    motion_mm: np.ndarray
    cells: SlowdownCells | None = None


class PlanGrid:
    """The path cut into planning cells, grouped into pieces between exact stops.

    Attributes:
        parent: (M,) segment of each cell.
        length_mm, s0_mm: (M,), (M+1,) cell lengths and start positions (s0 at every segment
            start is the path's own, exactly).
        vcap_mm_s, accel_mm_s2: (M,) F's limits of each cell.
        junction_mm_s: (M+1,) F's junction limits (inf between the cells of one segment).
        jerk_junction: (M+1,) bool, junctions F's classic jerk sets.
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
        v = forward_backward(vj, L, acc)
        tr = trapezoids(v, L, acc, vc, np.zeros(m), 0.0)
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


class TwinEvaluator:
    """The chance bound of sampled plans with the offline twin (TwinPredictor's prior)."""

    def __init__(self, tp, rules, *, z: float, tol_mm: float, overshoot_reach_mm: float,
                 ts_s: float = 0.002, offsets=None):
        self.tp = tp
        self.rules = rules
        self.ts_s = float(ts_s)
        self.z = float(z)
        self.tol = float(tol_mm)
        self.reach = float(overshoot_reach_mm)
        self.seg_tol = None
        #: samples of history that make a window's prediction exact (the twin's memory)
        self.memory = max(h.size for h in tp.h) + tp.maxlag + 1
        #: (function cmd (K, 2) -> (K, 2) mm, its memory) of the profile's extensions that
        #: add to the mean (twin.extensions.motion_offsets), or None
        self.offsets = None
        if offsets is not None:
            self.offsets = offsets[0]
            self.memory = max(self.memory, int(offsets[1]) + 1)

    def predict(self, cmd_xy: np.ndarray, ref_xy: np.ndarray):
        mean, std = predict_trajectory(self.tp, cmd_xy, ref=ref_xy)
        if self.offsets is not None:
            mean = mean + self.offsets(cmd_xy).T
        return mean, std

    def set_feature_tolerance(self, path, seg_tol_mm: np.ndarray) -> None:
        """Per-feature tolerance: (N,) E_max of each segment of ``path`` (inf: no contour
        constraint). ``self.tol`` stays the scalar (the tightest finite one) used where one
        number is needed (which samples get the exact distance)."""
        self.path = path
        self.seg_tol = np.asarray(seg_tol_mm, float)

    def tol_at(self, s: np.ndarray):
        """E_max of samples at arc length ``s``: the scalar, or each one's segment's."""
        if self.seg_tol is None:
            return self.tol
        return self.seg_tol[self.path.segment_at(s)]

    def geometry(self, path, s: np.ndarray, s_prev: np.ndarray,
                 s_next: np.ndarray | None = None) -> dict:
        """What the bound needs of sampled plans that does not depend on the prediction:
        commanded XY ``cmd`` (K, 2), unit normals ``nrm`` (K, 2), constrained samples ``on``
        (K,), and the overshoot pairs (``kk`` (m,), ``U``, ``V`` (m, 2)) of the samples near a
        sharp vertex. ``s_prev``, ``s_next``: (K,) the samples before and after each one."""
        s = np.asarray(s, float)
        on = self.rules.constrained_pairs(s, s_prev, s_next)
        kk, U, V = self.rules.overshoot_pairs(s, on, self.reach)
        return {"cmd": path.position(s)[:, :2], "nrm": _normals(path.tangent(s)[:, :2]),
                "on": on, "kk": kk, "U": U, "V": V}

    def bound(self, geo: dict, mean: np.ndarray, std: np.ndarray, *, idx=None, path_xy=None):
        """Chance bound (K,) (0 where unconstrained), its motion part (K,), and its uncertainty
        part zσ (K,), mm, of samples with geometry ``geo`` (:meth:`geometry`) and predicted XY
        mean and std (2, K).

        The motion part is the distance from the predicted position to the commanded path
        near it, as the virtual machine's metric measures it (vm.metrics: ±W thinned vertices
        of the plan's own commanded samples ``path_xy`` (N, 2), or a function that makes them
        (called only when a sample needs measuring); ``idx`` (K,) the samples' indices into
        it). The paper's projection on the normal at the commanded point (Eq. 6)
        misses the path curving away from a position that also lags along it, and running on
        past a corner (on a Benchy plan: 0.14 mm where the projection said 0.06). The
        distance is at most |command − position| (the command is on the path), which picks
        the samples worth measuring; the projection (and the overshoot rows) stand elsewhere.
        Without ``path_xy`` the projection is used everywhere."""
        nrm, on = geo["nrm"], geo["on"]
        err = geo["cmd"].T - mean
        mu = np.abs(nrm[:, 0] * err[0] + nrm[:, 1] * err[1])
        zsig = self.z * np.sqrt((nrm[:, 0] * std[0]) ** 2 + (nrm[:, 1] * std[1]) ** 2)
        motion = np.where(on, mu, 0.0)
        unc = np.where(on, zsig, 0.0)
        kk, U, V = geo["kk"], geo["U"], geo["V"]
        if kk.size:
            exc = np.sum(U * (mean[:, kk].T - V), axis=1)
            zs = self.z * np.sqrt((U[:, 0] * std[0, kk]) ** 2 + (U[:, 1] * std[1, kk]) ** 2)
            worse = exc + zs > motion[kk] + unc[kk]
            kk, exc, zs = kk[worse], exc[worse], zs[worse]
            # several vertices may reach one sample: keep the worst of each
            order = np.argsort(exc + zs)
            motion[kk[order]] = exc[order]
            unc[kk[order]] = zs[order]
        if path_xy is not None:
            dev = np.hypot(geo["cmd"][:, 0] - mean[0], geo["cmd"][:, 1] - mean[1])
            cand = np.flatnonzero(on & (dev + unc > self.tol * DISTANCE_CHECK))
            if cand.size:
                W = max(1, int(round(CONTOUR_WINDOW_S / self.ts_s)))
                poly = path_xy() if callable(path_xy) else path_xy
                d = distance_to_polyline_window(mean[:, cand].T, poly, W, index=idx[cand])
                del poly
                over = np.zeros(on.size, bool)
                over[kk] = True  # the overshoot rows stay where they say more
                motion[cand] = np.where(over[cand], np.maximum(motion[cand], d), d)
        return motion + unc, motion, unc


    def rest_error(self, geo: dict, idx: np.ndarray) -> np.ndarray:
        """(K,) the contour error of samples that no speed change removes, mm: none for the
        offline twin (a machine at rest is predicted exactly where it is commanded)."""
        return np.zeros(geo["on"].size)

    def rest_uncertainty(self) -> float:
        """zσ of a machine standing still, mm: the noise level and the bias of the axis that
        leaves most room (the uncertainty of the motion itself shrinks as it slows down)."""
        tp = self.tp
        s2 = np.broadcast_to(np.asarray(tp.s2, float), (len(tp.cov),))
        return self.z * float(np.sqrt(min(v + float(c[0, 0]) for v, c in zip(s2, tp.cov))))


class PlantEvaluator(TwinEvaluator):
    """The oracle's bound: the virtual machine's own plant, known exactly (zero std). Its
    effects may depend on absolute time or on the whole history, so it is always evaluated
    over the whole plan (``memory`` None)."""

    def __init__(self, plant, rules, *, z: float, tol_mm: float, overshoot_reach_mm: float):
        self.plant = plant
        self.rules = rules
        self.ts_s = float(plant.ts_s)
        self.z = float(z)
        self.tol = float(tol_mm)
        self.reach = float(overshoot_reach_mm)
        self.seg_tol = None
        self.memory = None
        self.effects = tuple(e for e in plant.effects if e.stage != "sensor")

    def predict(self, cmd_xy, ref_xy):
        cmd3 = np.column_stack([cmd_xy, np.zeros(cmd_xy.shape[0])])
        out = simulate_axes(cmd3, self.plant.ts_s, self.plant.impulse, self.effects,
                            mode_hz=self.plant.mode_hz).actual_mm
        return out[:, :2].T, np.zeros((2, cmd_xy.shape[0]))

    def rest_uncertainty(self) -> float:
        """The oracle knows its plant: no uncertainty (its disturbance is ``rest_error``)."""
        return 0.0

    def rest_error(self, geo: dict, idx: np.ndarray) -> np.ndarray:
        """(K,) what the plant's effects add at sample ``idx`` of a machine standing still,
        across the path (|n·d|), on constrained samples, mm: a time-periodic disturbance
        stays whatever the speed."""
        K = int(idx.max()) + 1 if idx.size else 0
        still = np.zeros((K, 3))
        d = simulate_axes(still, self.plant.ts_s, self.plant.impulse, self.effects,
                          mode_hz=self.plant.mode_hz).actual_mm[:, :2]
        nrm = geo["nrm"]
        return np.where(geo["on"], np.abs(nrm[:, 0] * d[idx, 0] + nrm[:, 1] * d[idx, 1]), 0.0)


def plan_bound(ev, path, s_mm: np.ndarray):
    """The chance bound of a whole sampled plan at once (K,), mm: what :func:`plan_slowdown`
    reports, computed from scratch (one whole-file prediction, no windows)."""
    s = np.asarray(s_mm, float)
    geo = ev.geometry(path, s, np.concatenate([s[:1], s[:-1]]), np.concatenate([s[1:], s[-1:]]))
    mean, std = ev.predict(geo["cmd"], geo["cmd"][0])
    return ev.bound(geo, mean, std, idx=np.arange(s.size), path_xy=geo["cmd"])[0]


_GEO_ROWS = ("cmd", "nrm", "on")
#: samples whose |command − predicted position| + zσ exceeds this fraction of E_max get the
#: distance to the path instead of the projection (below it the distance cannot break E_max)
DISTANCE_CHECK = 0.999
_FIELDS = ("b", "mot", "unc", "rest")


class _State:
    """The current plan of pieces [p0, p1) entry by entry, its bound, and which samples must
    be predicted again (NaN).

    Entry 0 is what comes before the first piece: sample 0 and the lead dwell when p0 = 0
    (judged like any sample), otherwise ``history`` — F's last samples before the group,
    which the twin remembers but which are not this state's to judge. Entry e ≥ 1 is piece
    p0 + e − 1 (motion samples, then the dwell held at its end)."""

    def __init__(self, path, grid: PlanGrid, ev, scale: np.ndarray, p0: int = 0,
                 p1: int | None = None, history: np.ndarray | None = None,
                 round_history: int = 150, plan: bool = True):
        self.path, self.grid, self.ev = path, grid, ev
        self.p0 = int(p0)
        self.p1 = grid.n_pieces if p1 is None else int(p1)
        P = self.p1 - self.p0
        self.cell_lo = int(grid.piece_cell[self.p0])
        self.cell_hi = int(grid.piece_cell[self.p1])
        self.scale = np.array(scale, float)
        self.piece_of = grid.piece_of_cell()
        self.end_s = grid.s0_mm[grid.piece_cell[1:]]
        self.start_s = grid.s0_mm[grid.piece_cell[:-1]]
        lead = np.zeros(grid.lead_hold + 1) if history is None else np.asarray(history, float)
        self.s = [lead] + [None] * P
        self.geo = [ev.geometry(path, lead, np.concatenate([lead[:1], lead[:-1]]))] + [None] * P
        if history is not None:  # remembered, not judged
            self.geo[0]["on"][:] = False
            self.geo[0]["kk"] = self.geo[0]["kk"][:0]
        self.tc0, self.tc1, self.v0 = [None] * P, [None] * P, [None] * P
        known = 0.0 if history is not None else np.nan  # history: remembered, never judged
        self.arr = {f: [np.full(lead.size, known)] + [None] * P for f in _FIELDS}
        self.mean = [np.full((2, lead.size), known)] + [None] * P
        #: per entry, samples whose values are carried over from a time-shifted old plan
        self.approx = [np.zeros(lead.size, bool)] + [None] * P
        self.ref = path.position(np.zeros(1))[0, :2]
        self.evaluated = 0
        self.evaluations = 0
        #: history (and reach after a change) of round predictions, samples
        self.reach = None if ev.memory is None else min(ev.memory, round_history)
        if plan:
            self._replan(np.arange(self.p0, self.p1))

    _PER_PIECE = ("tc0", "tc1", "v0")
    _PER_ENTRY = ("s", "geo", "mean", "approx")

    def export(self) -> dict:
        """This state's pieces (entries 1…), to be adopted by a state over more pieces."""
        out = {k: getattr(self, k) for k in self._PER_PIECE}
        out.update({k: getattr(self, k)[1:] for k in self._PER_ENTRY})
        out.update({f: self.arr[f][1:] for f in _FIELDS})
        out["p0"] = self.p0
        return out

    def adopt(self, part: dict) -> None:
        """Take another state's pieces as they are (planned, predicted, checked)."""
        q0 = part["p0"] - self.p0
        n = len(part["s"])
        for k in self._PER_PIECE:
            getattr(self, k)[q0:q0 + n] = part[k]
        for k in self._PER_ENTRY:
            getattr(self, k)[q0 + 1:q0 + 1 + n] = part[k]
        for f in _FIELDS:
            self.arr[f][q0 + 1:q0 + 1 + n] = part[f]

    # -- bookkeeping ----------------------------------------------------------------------
    def _invalidate(self, e: int, lo: int, hi: int | None = None):
        for f in _FIELDS:
            self.arr[f][e][lo:hi] = np.nan
        self.mean[e][:, lo:hi] = np.nan

    def invalidate_all(self):
        for e in range(len(self.s)):
            self._invalidate(e, 0)
            self.approx[e][:] = False

    def invalidate_approx(self):
        """Mark every carried-over (time-shifted) value for an exact prediction."""
        for e, ap in enumerate(self.approx):
            if ap.any():
                for f in _FIELDS:
                    self.arr[f][e][ap] = np.nan
                self.mean[e][:, ap] = np.nan
                ap[:] = False

    @property
    def n_approx(self) -> int:
        return int(sum(int(a.sum()) for a in self.approx))

    def _replan(self, pieces):
        """Re-plan ``pieces``; mark what must be predicted again (module docstring)."""
        g = self.grid
        ss, t0, t1, v0 = g.plan(self.scale, pieces)
        mem = self.reach
        fulls = [np.concatenate([x, np.full(g.piece_hold[p], self.end_s[p])])
                 for p, x in zip(pieces, ss)]
        # geometry of every re-planned sample in one vectorized pass
        if fulls:
            sizes = np.array([x.size for x in fulls])
            cat = np.concatenate(fulls)
            prev = np.concatenate([[0.0], cat[:-1]])
            starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
            prev[starts] = self.start_s[pieces]
            nxt = np.concatenate([cat[1:], [0.0]])
            ends = np.cumsum(sizes) - 1
            nxt[ends] = cat[ends]  # at rest at the piece's end: no interval after it here
            geo = self.ev.geometry(self.path, cat, prev, nxt)
            cut = np.cumsum(sizes)[:-1]
            rows = {k: np.split(geo[k], cut) for k in _GEO_ROWS}
            pair_cut = np.searchsorted(geo["kk"], cut)
            kk = np.split(geo["kk"], pair_cut)
            UU, VV = np.split(geo["U"], pair_cut), np.split(geo["V"], pair_cut)
        for i, (p, full, a, b, v) in enumerate(zip(pieces, fulls, t0, t1, v0)):
            e = int(p) - self.p0 + 1
            q = int(p) - self.p0
            old = self.s[e]
            n = full.size
            if old is not None and mem is not None:
                src, shifted, spill = self._warp(q, old.size, n, a, b, v, mem)
            else:
                src, shifted, spill = np.full(n, -1), np.zeros(n, bool), 0
            take = src >= 0
            self.s[e] = full
            self.geo[e] = {k: rows[k][i] for k in _GEO_ROWS}
            self.geo[e].update(kk=kk[i] - starts[i], U=UU[i], V=VV[i])
            self.tc0[q], self.tc1[q], self.v0[q] = a, b, v
            for f in _FIELDS:
                new = np.full(n, np.nan)
                if old is not None:
                    new[take] = self.arr[f][e][src[take]]
                self.arr[f][e] = new
            newm = np.full((2, n), np.nan)
            ap = np.zeros(n, bool)
            if old is not None:
                newm[:, take] = self.mean[e][:, src[take]]
                ap[take] = self.approx[e][src[take]] | shifted[take]
            self.mean[e], self.approx[e] = newm, ap
            if old is None or mem is None:
                continue
            # the next pieces' first samples remember this one's end: predicted again where
            # the changed stretch reaches into them, carried over (time-shifted) otherwise
            left, tail, nxt = spill, self.ev.memory, e + 1  # the twin's whole memory
            tail_approx = bool(n) and bool(ap[-1])
            while tail > 0 and nxt < len(self.s) and self.s[nxt] is not None:
                m_n = self.s[nxt].size
                if left > 0:
                    self._invalidate(nxt, 0, left)
                    self.approx[nxt][:left] = False
                if tail_approx:
                    self.approx[nxt][max(left, 0):tail] = True
                left -= m_n
                tail -= m_n
                nxt += 1
        if mem is None:
            self.invalidate_all()

    def _warp(self, q: int, old_n: int, n: int, a, b, v, reach: int):
        """Where a re-planned piece's new samples find their old values.

        A cell whose motion did not change (same duration, entry and exit speed) moves as
        before, only later by the delay of the changed cells before it: its new sample at
        local time t is the old sample at the corresponding old time (the nearest whole
        sample; ``shifted`` when the delay is not zero). Samples in changed cells and within
        ``reach`` samples after them have no old value (src −1): they are predicted again.

        Returns src (n,) old index or −1, shifted (n,) bool, and how many samples the last
        changed stretch reaches past the piece's end (into the next pieces)."""
        ts = self.grid.ts_s
        a0, b0 = self.tc0[q], self.tc1[q]
        C = a.size
        vn, vo = np.append(v, 0.0), np.append(self.v0[q], 0.0)
        changed = ((b - a) != (b0 - a0)) | (vn[:-1] != vo[:-1]) | (vn[1:] != vo[1:])
        if not changed.any() and old_n == n:
            return np.arange(n), np.zeros(n, bool), 0
        t = np.arange(1, n + 1) * ts
        c = np.clip(np.searchsorted(a, t, side="right") - 1, 0, C - 1)
        last = np.maximum.accumulate(np.where(changed, np.arange(C), -1))[c]
        end_last = np.where(last >= 0, b[np.maximum(last, 0)], -np.inf)
        dirty = (t - end_last) < reach * ts
        rest = t > b[-1]
        t_old = np.where(rest, t - (b[-1] - b0[-1]), a0[c] + (t - a[c]))
        j = np.rint(t_old / ts).astype(np.int64) - 1
        ok = ~dirty & (j >= 0) & (j < old_n)
        src = np.where(ok, j, -1)
        shifted = ok & (last >= 0)
        spill = 0
        if changed.any():
            end = float(b[np.flatnonzero(changed)[-1]]) + reach * ts
            spill = max(0, int(np.ceil(end / ts - 1e-9)) - n)
        return src, shifted, spill

    def set_scale(self, scale: np.ndarray):
        changed = np.flatnonzero(scale != self.scale)
        self.scale = np.array(scale, float)
        if changed.size:
            self._replan(np.unique(self.piece_of[changed]))

    # -- evaluation -------------------------------------------------------------------------
    def assemble(self):
        """Global s (K,), {b, mot, unc} (K,), mean (2, K), and the sample offset of every
        entry (E,)."""
        sizes = np.array([x.size for x in self.s], np.int64)
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        s = np.concatenate(self.s)
        out = {f: np.concatenate(self.arr[f]) for f in _FIELDS}
        mean = np.concatenate(self.mean, axis=1)
        return s, out, mean, starts

    def _gather(self, idx: np.ndarray, starts: np.ndarray) -> dict:
        """The cached geometry of global samples ``idx`` (sorted), overshoot pairs numbered by
        position in ``idx``."""
        bounds = np.searchsorted(idx, np.concatenate([starts, [np.iinfo(np.int64).max]]))
        parts = {k: [] for k in _GEO_ROWS}
        kk, U, V = [], [], []
        for e in np.flatnonzero(np.diff(bounds) > 0):
            lo, hi = bounds[e], bounds[e + 1]
            loc = idx[lo:hi] - starts[e]
            g = self.geo[e]
            for k in _GEO_ROWS:
                parts[k].append(g[k][loc])
            if g["kk"].size:
                pos = np.clip(np.searchsorted(loc, g["kk"]), 0, loc.size - 1)
                hit = loc[pos] == g["kk"]
                kk.append(pos[hit] + lo)
                U.append(g["U"][hit])
                V.append(g["V"][hit])
        out = {k: np.concatenate(v) for k, v in parts.items()}
        out["kk"] = np.concatenate(kk) if kk else np.zeros(0, np.int64)
        out["U"] = np.concatenate(U) if U else np.zeros((0, 2))
        out["V"] = np.concatenate(V) if V else np.zeros((0, 2))
        return out

    def evaluate(self, exact: bool = False):
        """Predict every sample whose bound is unknown; returns :meth:`assemble`'s values.

        ``exact``: with the twin's whole memory of history before every window and the whole
        plan's reference (equal to the whole-file prediction); otherwise with
        ``self.reach`` samples of history, each window from its own first command, and the
        values flagged ``approx`` for the next whole-file check."""
        s, out, mean, starts = self.assemble()
        bad = np.isnan(out["b"])
        if not bad.any():
            return s, out, mean, starts
        mem = self.ev.memory if exact else self.reach
        if mem is None:
            w_lo, w_hi = np.array([0]), np.array([s.size])
            exact = True
        else:
            edge = np.diff(np.concatenate([[0], bad.astype(np.int8), [0]]))
            a_runs, b_runs = np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)
            # each run with its history before it; overlapping ones merge
            h_lo = np.maximum(a_runs - mem, 0)
            first = np.concatenate([[True], h_lo[1:] > b_runs[:-1]])
            w_lo = h_lo[first]
            w_hi = np.maximum.reduceat(b_runs, np.flatnonzero(first))
        owner, idx = ranges(w_lo, w_hi)
        geo = self._gather(idx, starts)
        if exact:
            ref = self.ref
        else:
            ref = geo["cmd"][np.concatenate([[0], np.cumsum(w_hi - w_lo)[:-1]])][owner]
        mu, sd = self.ev.predict(geo["cmd"], ref)
        vals = self.ev.bound(geo, mu, sd, idx=idx,
                             path_xy=lambda: np.concatenate([g["cmd"] for g in self.geo]))
        vals = vals + (self.ev.rest_error(geo, idx),)
        fill = bad[idx]
        tgt = idx[fill]
        for f, v in zip(_FIELDS, vals):
            out[f][tgt] = v[fill]
        mean[:, tgt] = mu[:, fill]
        self.evaluated += int(idx.size)
        self.evaluations += 1
        cut = starts[1:]
        for f in _FIELDS:
            self.arr[f] = np.split(out[f], cut)
        self.mean = np.split(mean, cut, axis=1)
        if not exact:
            # a window from the plan's first sample has its whole history: exact
            ap = np.concatenate(self.approx)
            ap[tgt] = (w_lo[owner] > 0)[fill]
            self.approx = np.split(ap, cut)
        return s, out, mean, starts

    def cell_times(self, starts):
        """Global motion start and end time of this state's cells, s (entry e's local time 0
        is the resting sample before its first motion sample)."""
        base = (starts[1:] - 1) * self.grid.ts_s
        t0 = np.concatenate([c + b for c, b in zip(self.tc0, base)])
        t1 = np.concatenate([c + b for c, b in zip(self.tc1, base)])
        return t0, t1


def _optimize(state: _State, st: SlowdownSettings, relaxed: np.ndarray, *, grow: bool) -> dict:
    """Slow down, grow back (``grow``), and check on the whole plan (module docstring)."""
    grid = state.grid
    tol = state.ev.tol
    ts = grid.ts_s
    lo_c, hi_c = state.cell_lo, state.cell_hi
    lo_f, hi_f = st.step
    stats = {"rounds": 0, "whole_file_checks": 0}

    cur = {}

    def violations(exact=False):
        s, out, mean, starts = state.evaluate(exact)
        tol_s = state.ev.tol_at(s)
        viol = np.flatnonzero(out["b"] > tol_s)
        # the violated samples' E_max: the scalar (bit-identical single-tolerance path) or
        # each sample's feature's
        cur["tol"] = tol if np.ndim(tol_s) == 0 else tol_s[viol]
        return viol, out, starts

    def cause(starts, k, widen):
        t0, t1 = state.cell_times(starts)
        t = k * ts
        lo = np.searchsorted(t1, t - st.cause_before_s * widen, side="left")
        hi = np.searchsorted(t0, t + st.cause_after_s, side="right")
        owner, cells = ranges(lo, hi)
        return owner, cells + lo_c

    def settle():
        for rnd in range(st.max_rounds):
            viol, out, starts = violations()
            if viol.size == 0:
                return
            stats["rounds"] += 1
            late = max(0, rnd - st.escalate_after + 1)
            widen = 2.0 ** min((late + 1) // 2, 3)
            cap = max(hi_f - 0.05 * late, 0.8) if late else hi_f
            # the part of the error that no speed changes (a disturbance at rest: the plant's,
            # for the oracle; 0 for the twin, whose offline error vanishes at rest)
            rest = out["rest"][viol]
            # the uncertainty of the motion shrinks with it: only the evaluator's uncertainty
            # at rest (u0) stays; zσ lies below the chord u0 + g·(zσ − u0) as the motion part
            # of σ scales by g, so the factor below never under-slows against the full zσ
            u0 = state.ev.rest_uncertainty()
            room = st.aim * cur["tol"] - u0 - rest
            moving = out["mot"][viol] + np.maximum(out["unc"][viol] - u0, 0.0) - rest
            f = np.clip((np.maximum(room, 0.0) / np.maximum(moving, 1e-12)) ** st.exponent,
                        lo_f, cap)
            scale = state.scale
            stuck = (scale <= st.scale_min * (1 + 1e-9)) | grid.fixed
            # a window whose every cell is already at the floor has its cause further back (a
            # hard stop before a slowed stretch rings for a few periods of the mode): look back
            # twice as far, up to ``max_cause_before_s``, before calling the violation hopeless
            w_v = np.full(viol.size, widen)
            owner, cells = cause(starts, viol, widen)
            at_floor = np.ones(viol.size, bool)
            np.logical_and.at(at_floor, owner, stuck[cells])
            while True:
                sub = np.flatnonzero(at_floor & (st.cause_before_s * w_v < st.max_cause_before_s))
                if sub.size == 0:
                    break
                w_v[sub] *= 2.0
                keep = ~np.isin(owner, sub)
                o2, c2 = [], []
                for w in np.unique(w_v[sub]):
                    part = sub[w_v[sub] == w]
                    o, c = cause(starts, viol[part], w)
                    o2.append(part[o])
                    c2.append(c)
                owner = np.concatenate([owner[keep], *o2])
                cells = np.concatenate([cells[keep], *c2])
                at_floor = np.ones(viol.size, bool)
                np.logical_and.at(at_floor, owner, stuck[cells])
            fac = np.ones(grid.n_cells)
            np.minimum.at(fac, cells, f[owner])
            fac[grid.fixed | relaxed] = 1.0
            # a violation that standing still would not cure (the error at rest, and the
            # evaluator's uncertainty at rest, leave no room), or whose widest cause window is
            # at the floor, is not the motion's: give up on it and give its cells their speed
            # back
            hopeless_v = room <= 0.0
            hopeless_v |= at_floor
            new = np.maximum(scale * fac, st.scale_min)
            if hopeless_v.any():
                hopeless = np.zeros(grid.n_cells, bool)
                hopeless[cells[hopeless_v[owner]]] = True
                relaxed[hopeless] = True
                new = np.where(hopeless, 1.0, new)
            if np.array_equal(new, scale):
                return
            state.set_scale(new)

    settle()
    for g in (st.grow if grow else ()):
        slow = (state.scale < 1.0) & ~relaxed
        slow[:lo_c] = slow[hi_c:] = False
        if not slow.any():
            break
        before = state.scale.copy()
        state.set_scale(np.where(slow, np.minimum(1.0, before * g), before))
        viol, out, starts = violations()
        if viol.size:
            _, cells = cause(starts, viol, 1.5)
            back = np.zeros(grid.n_cells, bool)
            back[cells] = True
            state.set_scale(np.where(back, before, state.scale))
        settle()
    # values carried over from shifted plans are replaced by exact predictions; settle
    # again where that reveals a violation
    for _ in range(st.max_checks):
        stats["whole_file_checks"] += 1
        state.invalidate_approx()
        if violations(exact=True)[0].size == 0:
            break
        settle()
    return stats


_CTX: dict = {}


def _optimize_group(p0: int, p1: int):
    """Worker: optimize pieces [p0, p1) from F's history before them (forked process)."""
    c = _CTX
    grid, st = c["grid"], c["settings"]
    hist = c["history"].get(p0)
    state = _State(c["path"], grid, c["evaluator"], np.ones(grid.n_cells), p0, p1, hist,
                   round_history=max(1, int(round(st.round_history_s / grid.ts_s))))
    relaxed = np.zeros(grid.n_cells, bool)
    stats = _optimize(state, st, relaxed, grow=True)
    a, b = state.cell_lo, state.cell_hi
    stats.update(evaluations=state.evaluations, samples_evaluated=state.evaluated)
    return a, b, state.scale[a:b], relaxed[a:b], stats, state.export()


def _groups(grid: PlanGrid, workers: int, group_samples: int):
    """Contiguous piece ranges with about equal samples of F each (a multiple of ``workers``
    of them, enough that none holds more than about ``group_samples``), and F's plan of
    every piece."""
    ss, _, _, _ = grid.plan(np.ones(grid.n_cells), np.arange(grid.n_pieces))
    sizes = np.array([x.size for x in ss]) + grid.piece_hold
    cum = np.cumsum(sizes)
    # a multiple of the workers, so none waits idle at the end (groups of equal length)
    n_groups = workers * int(np.ceil(cum[-1] / max(workers * group_samples, 1)))
    cuts = [0]
    for g in range(1, n_groups):
        i = int(np.searchsorted(cum, cum[-1] * g / n_groups)) + 1
        if cuts[-1] < i < grid.n_pieces:
            cuts.append(i)
    cuts.append(grid.n_pieces)
    return list(zip(cuts[:-1], cuts[1:])), ss, int(cum[-1])


def _cell_peaks(grid: PlanGrid, state: _State) -> np.ndarray:
    """(M,) the plan's highest speed in every cell, mm/s: its trapezoid's peak
    (plan.trapezoid.trapezoids) from the cell's entry speed, the next cell's (0 after a
    piece's last cell: pieces end at rest), and its scaled acceleration and feed cap. A run of
    cells the writer gives one acceleration is one firmware trapezoid, and this is its F."""
    v0 = np.concatenate(state.v0)
    v1 = np.append(v0[1:], 0.0)
    v1[grid.piece_cell[1:] - 1] = 0.0
    r = state.scale
    return peak_speed(v0, v1, grid.accel_mm_s2 * r * r, grid.length_mm, grid.vcap_mm_s * r)


def plan_slowdown(path, limits: PlannerLimits, evaluator, *, ts_s: float,
                  settings: SlowdownSettings | None = None) -> SlowdownResult:
    """Slow the firmware's plan down locally until the evaluator's chance bound holds on
    every sample (module docstring). ``limits``: plan.kinematic.planner_limits of the path
    (F's limits); ``evaluator``: TwinEvaluator or PlantEvaluator."""
    global _CTX
    st = settings or SlowdownSettings()
    t_start = time.perf_counter()
    grid = PlanGrid(path, limits, st.grid_mm, ts_s)
    scale = np.ones(grid.n_cells)
    relaxed = np.zeros(grid.n_cells, bool)
    workers = parallel.default_workers() if st.workers is None else int(st.workers)
    info = {"workers": 1}
    group_stats = []
    if workers > 1 and evaluator.memory is not None and grid.n_pieces > 1:
        groups, ss, total = _groups(grid, workers, st.group_samples)
        if total >= st.min_parallel_samples and len(groups) > 1:
            mem = evaluator.memory
            history = {}
            for p0, _ in groups[1:]:
                before = [np.zeros(grid.lead_hold + 1)] + [
                    np.concatenate([ss[p], np.full(grid.piece_hold[p], grid.s0_mm[grid.piece_cell[p + 1]])])
                    for p in range(max(0, p0 - mem), p0)]
                # a copy: a view would keep the whole concatenation (up to ``mem`` pieces)
                # alive, 3 GB over the ArcWelder Benchy's groups
                history[p0] = np.concatenate(before)[-mem:].copy()
            _CTX = {"grid": grid, "settings": st, "history": history, "path": path,
                    "evaluator": evaluator}
            try:
                # workers stopped on Ctrl-C/SIGTERM/any error, never left blocked (procs.py)
                with worker_pool(min(workers, len(groups)), mp.get_context("fork")) as pool:
                    parts = list(pool.map(_optimize_group, *zip(*groups)))
            finally:
                _CTX = {}
            for a, b, sc, rl, stt, _ in parts:
                scale[a:b] = sc
                relaxed[a:b] = rl
                group_stats.append(stt)
            info["workers"] = min(workers, len(groups))
            info["groups"] = len(groups)
            info["groups_s"] = time.perf_counter() - t_start
    round_history = max(1, int(round(st.round_history_s / ts_s)))
    if group_stats:
        # the groups' plans as they are; only what follows a group boundary remembers a
        # different history than the group assumed (F's): predict that again, exactly
        state = _State(path, grid, evaluator, scale, round_history=round_history, plan=False)
        for part in parts:
            state.adopt(part[5])
        for p0, _ in groups[1:]:
            left, e = evaluator.memory, p0 + 1
            while left > 0 and e < len(state.s):
                state._invalidate(e, 0, left)
                left -= state.s[e].size
                e += 1
        del parts
    else:
        state = _State(path, grid, evaluator, scale, round_history=round_history)
    t_merge = time.perf_counter()
    stats = _optimize(state, st, relaxed, grow=not group_stats)
    state.invalidate_approx()  # no-op unless the check budget ran out: report exact values
    s, out, mean, _ = state.evaluate(exact=True)
    b = out["b"]
    cell_len = grid.length_mm
    info.update({
        "optimizer": "slowdown",
        "rounds": stats["rounds"] + sum(g["rounds"] for g in group_stats),
        "whole_file_checks": stats["whole_file_checks"],
        "evaluations": state.evaluations + sum(g["evaluations"] for g in group_stats),
        "samples_evaluated": state.evaluated + sum(g["samples_evaluated"] for g in group_stats),
        "relaxed_samples": int(np.sum(b > evaluator.tol_at(s))),
        "grid_cells": grid.n_cells,
        "slowed_length_fraction": float(np.sum(cell_len[state.scale < 1.0]) /
                                        max(float(np.sum(cell_len)), 1e-12)),
        "scale_min_used": float(state.scale.min()) if state.scale.size else 1.0,
        "compute_s": time.perf_counter() - t_start,
        "settle_s": time.perf_counter() - t_merge,
    })
    cells = SlowdownCells(s0_mm=grid.s0_mm, parent=grid.parent, scale=state.scale,
                          accel_mm_s2=grid.accel_mm_s2 * state.scale * state.scale,
                          vcap_mm_s=grid.vcap_mm_s * state.scale,
                          vpeak_mm_s=_cell_peaks(grid, state), jerk_junction=grid.jerk_junction)
    return SlowdownResult(s_mm=s, scale=state.scale, info=info, mean_xy_mm=mean.T,
                          bound_mm=b, motion_mm=out["mot"], cells=cells)
