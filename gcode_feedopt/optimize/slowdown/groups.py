"""The slow-down of long files in worker groups (optimize.slowdown): contiguous groups of
pieces planned in forked worker processes, each from F's history before it, then taken into
one state whose samples right after each group boundary are predicted again."""

from __future__ import annotations

import multiprocessing as mp
import time
from typing import TYPE_CHECKING

import numpy as np

from ...procs import worker_pool
from .grid import PlanGrid
from .loop import optimize
from .state import PlanState

if TYPE_CHECKING:
    from . import SlowdownSettings

_CTX: dict = {}


def _optimize_group(p0: int, p1: int):
    """Worker: optimize pieces [p0, p1) from F's history before them (forked process)."""
    c = _CTX
    grid, st = c["grid"], c["settings"]
    hist = c["history"].get(p0)
    state = PlanState(c["path"], grid, c["evaluator"], np.ones(grid.n_cells), p0, p1, hist,
                      round_history=max(1, int(round(st.round_history_s / grid.ts_s))))
    relaxed = np.zeros(grid.n_cells, bool)
    stats = optimize(state, st, relaxed, grow=True)
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


def _histories(grid: PlanGrid, groups, ss, mem: int) -> dict:
    """F's last ``mem`` samples before every group but the first (what its twin remembers)."""
    history = {}
    for p0, _ in groups[1:]:
        before = [np.zeros(grid.lead_hold + 1)] + [
            np.concatenate([ss[p], np.full(grid.piece_hold[p], grid.s0_mm[grid.piece_cell[p + 1]])])
            for p in range(max(0, p0 - mem), p0)]
        # a copy: a view would keep the whole concatenation (up to ``mem`` pieces)
        # alive, 3 GB over the ArcWelder Benchy's groups
        history[p0] = np.concatenate(before)[-mem:].copy()
    return history


def plan_in_groups(path, grid: PlanGrid, evaluator, st: SlowdownSettings, workers: int,
                   scale: np.ndarray, relaxed: np.ndarray, info: dict, t_start: float,
                   round_history: int):
    """Plan the file in worker groups when it is long enough (``st.min_parallel_samples``)
    and ``workers`` > 1; returns the state of the whole file with the groups' plans (their
    scales and relaxed cells written into ``scale`` and ``relaxed``, the figures into
    ``info``) and each group's stats, or (None, []) to plan it in one process."""
    global _CTX
    if not (workers > 1 and evaluator.memory is not None and grid.n_pieces > 1):
        return None, []
    groups, ss, total = _groups(grid, workers, st.group_samples)
    if not (total >= st.min_parallel_samples and len(groups) > 1):
        return None, []
    history = _histories(grid, groups, ss, evaluator.memory)
    _CTX = {"grid": grid, "settings": st, "history": history, "path": path,
            "evaluator": evaluator}
    try:
        # workers stopped on Ctrl-C/SIGTERM/any error, never left blocked (procs.py)
        with worker_pool(min(workers, len(groups)), mp.get_context("fork")) as pool:
            parts = list(pool.map(_optimize_group, *zip(*groups)))
    finally:
        _CTX = {}
    group_stats = []
    for a, b, sc, rl, stt, _ in parts:
        scale[a:b] = sc
        relaxed[a:b] = rl
        group_stats.append(stt)
    info["workers"] = min(workers, len(groups))
    info["groups"] = len(groups)
    info["groups_s"] = time.perf_counter() - t_start
    # the groups' plans as they are; only what follows a group boundary remembers a
    # different history than the group assumed (F's): predict that again, exactly
    state = PlanState(path, grid, evaluator, scale, round_history=round_history, plan=False)
    for part in parts:
        state.adopt(part[5])
    del parts
    for p0, _ in groups[1:]:
        left, e = evaluator.memory, p0 + 1
        while left > 0 and e < len(state.s):
            state._invalidate(e, 0, left)
            left -= state.s[e].size
            e += 1
    return state, group_stats
