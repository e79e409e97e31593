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
2. **Plan.** The firmware's own look-ahead (plan.trapezoid.forward_backward and trapezoids;
   Klipper's with minimum_cruise_ratio's pseudo-accel, firmware.klipper.klipper_lookahead)
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
   window) gets a wider window and a firmer step. Repeat until no sample violates. A sample
   over its bound whose predicted mean is within E_max is no violation while the stringency's
   budget carries it (budget.py: η is the share of samples within, ``budget_share``); one
   whose mean is beyond is first slowed until its mean is within.
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
the stop, before the window), are given up on, counted in ``info["relaxed_samples"]``. Where
standing still would not cure them their cells return to full speed (slowing them down does not
help); where their whole cause window is at the floor they stay there: at the floor the twin
still expects less error than at full speed, and a machine whose twin cannot promise the
tolerance at any speed it may choose runs the slowest plan it may (tests/foreign, seed 164:
3,055 samples given up at full speed ran 238 µm RMS γ where 2.5 were allowed; kept at the floor,
0.00). The twin's uncertainty is mostly the motion's own (the spread of the FRFs acts on the
command's deviations), so a step's factor counts only the uncertainty at rest as fixed and
scales the rest with the motion.

The plan stays within F everywhere (every limit is F's limit times r ≤ 1); ``cells`` of the
result tell the writer where and how much it was slowed.

The modules, one step each (imports go one way, this module → groups → loop → state → grid):
grid.py (PlanGrid: steps 1–2), evaluators.py (TwinEvaluator, PlantEvaluator: step 3),
state.py (PlanState: the current plan, what is predicted again, windowed prediction),
loop.py (steps 4–5 and the whole-file checks), budget.py (the stringency's budget, pure),
groups.py (worker groups); here the settings, the result and :func:`plan_slowdown`.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from ...gcode.schedule import SlowdownCells
from ...plan.kinematic import PlannerLimits
from ...plan.trapezoid import peak_speed
from .. import parallel
from .budget import expected_share, left_over
from .grid import PlanGrid
from .groups import plan_in_groups
from .loop import budgeted, optimize, room_at_rest
from .state import PlanState


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
    #: share of the stringency's room (1 − η of the samples out, RMS γ (1 − η)·E_max) that
    #: samples over their bound but with the mean within may spend, in expectation under the
    #: twin (slowdown.budget); 0: the bound on every sample (the paper's constraint)
    budget_share: float = 0.5
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

    def seeing_out(self, ring_s: float) -> "SlowdownSettings":
        """These settings on a machine that rings (or settles) for ``ring_s``
        (twin.physics.memory_time_s):
        a stretch's rounds are predicted with at least 1.5·ring_s of history, and a
        violation looks back up to 2.5·ring_s for its cause. The defaults were measured on
        machines that ring for 0.16–0.28 s; on a corexy that rings for 0.94 s (tests/foreign, seed 0)
        the rounds missed the ringing entering slowed stretches and gave up 4,088 samples
        (on the plant 89.3 % of the samples within tolerance); seeing it out, none is given up
        and all are within (docs/optimizer.md §4). History and look-back are taken at the
        ratios the defaults have on ender3pro, which rings for 0.18 s."""
        return dataclasses.replace(
            self, round_history_s=max(self.round_history_s, 1.5 * ring_s),
            max_cause_before_s=max(self.max_cause_before_s, 2.5 * ring_s))


@dataclass
class SlowdownResult:
    """What :func:`plan_slowdown` returns.

    Attributes:
        s_mm: (K,) path position at t_k = k·Ts, mm.
        scale: (M,) final scale of every grid cell.
        info: rounds, evaluations, samples evaluated, relaxed (given-up) samples, samples
            the stringency's budget carries and the expected share within and RMS γ,
            compute seconds, fraction of length slowed, workers.
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


def _cell_peaks(grid: PlanGrid, state: PlanState) -> np.ndarray:
    """(M,) the plan's highest speed in every cell, mm/s: its trapezoid's peak
    (plan.trapezoid.trapezoids) from the cell's entry speed, the next cell's (0 after a
    piece's last cell: pieces end at rest), and its scaled acceleration and feed cap. A run of
    cells the writer gives one acceleration is one firmware trapezoid, and this is its F."""
    v0 = np.concatenate(state.v0)
    v1 = np.append(v0[1:], 0.0)
    v1[grid.piece_cell[1:] - 1] = 0.0
    r = state.scale
    return peak_speed(v0, v1, grid.accel_mm_s2 * r * r, grid.length_mm, grid.vcap_mm_s * r)


def _at_rest(given_up, out, tol, evaluator, st: SlowdownSettings) -> int:
    """How many of the ``given_up`` samples standing still would not cure (loop.room_at_rest)."""
    if given_up.size == 0:
        return 0
    viol_tol = tol if np.ndim(tol) == 0 else np.asarray(tol)[given_up]
    room, _ = room_at_rest(out, given_up, viol_tol, evaluator.rest_uncertainty(), st.aim,
                           budgeted(st, evaluator))
    return int(np.count_nonzero(room <= 0.0))


def plan_slowdown(path, limits: PlannerLimits, evaluator, *, ts_s: float,
                  settings: SlowdownSettings | None = None) -> SlowdownResult:
    """Slow the firmware's plan down locally until the evaluator's chance bound holds on
    every sample but those the stringency's budget carries (module docstring). ``limits``: plan.kinematic.planner_limits of the path
    (F's limits); ``evaluator``: TwinEvaluator or PlantEvaluator."""
    st = settings or SlowdownSettings()
    t_start = time.perf_counter()
    grid = PlanGrid(path, limits, st.grid_mm, ts_s)
    scale = np.ones(grid.n_cells)
    relaxed = np.zeros(grid.n_cells, bool)
    workers = parallel.default_workers() if st.workers is None else int(st.workers)
    info = {"workers": 1}
    round_history = max(1, int(round(st.round_history_s / ts_s)))
    state, group_stats = plan_in_groups(path, grid, evaluator, st, workers, scale, relaxed,
                                        info, t_start, round_history)
    if state is None:
        state = PlanState(path, grid, evaluator, scale, round_history=round_history)
    t_merge = time.perf_counter()
    stats = optimize(state, st, relaxed, grow=not group_stats)
    state.invalidate_approx()  # no-op unless the check budget ran out: report exact values
    s, out, mean, _ = state.evaluate(exact=True)
    b = out["b"]
    tol = evaluator.tol_at(s)
    over = np.flatnonzero(b > tol)
    given_up = left_over(over, out, tol, evaluator.z, st.budget_share)
    on = b > 0
    sd = out["unc"] / evaluator.z if evaluator.z > 0 else np.zeros_like(b)
    p_out, rms_g = expected_share(out["mot"], sd, tol, on)
    cell_len = grid.length_mm
    info.update({
        "optimizer": "slowdown",
        "rounds": stats["rounds"] + sum(g["rounds"] for g in group_stats),
        "whole_file_checks": stats["whole_file_checks"],
        "evaluations": state.evaluations + sum(g["evaluations"] for g in group_stats),
        "samples_evaluated": state.evaluated + sum(g["samples_evaluated"] for g in group_stats),
        "relaxed_samples": int(given_up.size),
        # of those, the ones standing still would not cure (run at the firmware's speed);
        # the rest run at the floor, where the twin still expects less error than at speed
        "relaxed_at_rest_samples": _at_rest(given_up, out, tol, evaluator, st),
        # zσ of a machine standing still, mm: what no speed changes (the noise level, a bias)
        "rest_uncertainty_mm": float(evaluator.rest_uncertainty()),
        # samples over their bound that the stringency's budget carries (slowdown.budget)
        "budget_samples": int(over.size - given_up.size),
        # under the twin's Gaussian prediction: the expected share of the constrained
        # samples within tolerance, and the expected RMS γ, mm
        "predicted_within_fraction": 1.0 - p_out, "predicted_rms_gamma_mm": rms_g,
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
