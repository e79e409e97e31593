"""Plan independent stretches of a print in parallel processes (offline twin methods).

Exact stops (retractions, dwells, tool changes, ...) cut a print into pieces that start and
end at rest; the receding-window planner of one piece needs only the *recent* command
history (the twin's memory: n_taps samples of the impulse response and the n2/n3 feature
lags), not the plan of the whole print. A chunk of consecutive pieces is therefore planned
in a worker from the free plan F's history before it (the plan there is F wherever the
tolerance is slack; where an earlier chunk slowed down, the machine has come to rest at the
stop between them — the twin is time-invariant, so only the last samples matter).

Afterwards the whole merged plan is predicted once more (predictors.predict_trajectory, the
sequential twin exactly) and its worst predicted contour error is what the report states;
a piece whose start the history approximation pushed over the tolerance is planned again
sequentially with its true history (counted as ``repaired_pieces``).
"""

from __future__ import annotations

import multiprocessing as mp
import os

import numpy as np

from ..errors import UsageError
from ..procs import worker_pool
from .predictors import predict_trajectory

#: history handed to a worker, samples (≥ the twin's n_taps + feature lags)
HISTORY_PAD = 64
#: chunks per worker (load balance: the LP-heavy stretches are not evenly spread)
CHUNKS_PER_WORKER = 16
#: below this many free-plan samples the process start-up is not worth it
MIN_PARALLEL_SAMPLES = 60_000

_CTX: dict = {}


def default_workers() -> int:
    env = os.environ.get("GCODE_FEEDOPT_JOBS")
    if env:
        if not env.strip().isdigit() or not 1 <= int(env) <= 256:
            raise UsageError(f"GCODE_FEEDOPT_JOBS={env[:20]!r} is not a whole number from 1 to "
                             "256; set it so or unset it")
        return int(env)
    return max(1, min(os.cpu_count() or 1, 8))


def chunk_pieces(piece_samples: np.ndarray, n_chunks: int) -> list[tuple[int, int]]:
    """Contiguous [i0, i1) ranges of pieces with about equal free-plan samples each."""
    n = piece_samples.size
    n_chunks = max(1, min(n_chunks, n))
    cum = np.cumsum(piece_samples)
    total = float(cum[-1]) if n else 0.0
    cuts = [0]
    for c in range(1, n_chunks):
        i = int(np.searchsorted(cum, total * c / n_chunks)) + 1
        if cuts[-1] < i < n:
            cuts.append(i)
    cuts.append(n)
    return list(zip(cuts[:-1], cuts[1:]))


def _run_chunk(i0: int, i1: int):
    """Plan pieces i0..i1−1 in this (forked) process; returns (s_new, info, pred lists)."""
    c = _CTX
    planner, pred = c["make_planner"]()
    pieces = c["pieces"]
    fs = c["F_s"]
    ts = c["ts"]
    if i0 == 0:
        planner.start(0.0)
        planner.hold(int(round(c["dwell_before_s"] / ts)))
        H = 0
    else:
        # F's history up to (and at rest on) the stop before the chunk
        s_a = pieces[i0 - 1][0]
        k_a, ser, mean, std = c["hist"][i0]
        H = mean.shape[1]
        pred.load_history(c["ref"], ser, mean, std)
        planner.s_hist = [float(v) for v in fs[k_a - H:k_a]]
        planner.s_hist[-1] = s_a  # at rest exactly on the stop
        planner.cmd_hist = list(c["path"].position(np.asarray(planner.s_hist))[:, :2])
    for s_end, dwell_s, _ in pieces[i0:i1]:
        planner.run_piece(s_end)
        planner.hold(int(round(dwell_s / ts)))
    res = planner.result()
    return (np.asarray(res.s_mm[H:], float), res.info,
            [np.asarray(pred.pred_mean[a][H:]) for a in range(2)])


def run_parallel(ctx: dict, n_workers: int):
    """Plan all pieces of ``ctx`` in chunks over ``n_workers`` forked processes.

    Returns (s_mm, merged info, predicted XY (K, 2))."""
    global _CTX
    pieces = ctx["pieces"]
    fs = ctx["F_s"]
    ends = np.array([p[0] for p in pieces])
    idx = np.searchsorted(fs, ends, side="left")
    samples = np.diff(np.concatenate([[0], idx]))
    chunks = chunk_pieces(samples, n_workers * CHUNKS_PER_WORKER)
    # the twin's internal series along F, kept only just before each chunk
    pred0 = ctx["predictor"]
    cmd = ctx["path"].position(fs)[:, :2]
    mean, std, series = predict_trajectory(pred0, cmd, series=True)
    H = ctx["history"]
    hist = {}
    for i0, _ in chunks:
        if i0 == 0:
            continue
        s_a = pieces[i0 - 1][0]
        k_a = max(int(np.searchsorted(fs, s_a + 1e-9, side="left")), 1)
        lo = max(0, k_a - H)
        hist[i0] = (k_a, [tuple(np.array(v[lo:k_a]) for v in ax) for ax in series],
                    mean[:, lo:k_a].copy(), std[:, lo:k_a].copy())
    del mean, std, series, cmd
    ctx = dict(ctx, hist=hist, ref=pred0.ref if pred0.ref is not None else
               ctx["path"].position(fs[:1])[0, :2])
    _CTX = ctx
    try:
        # workers stopped on Ctrl-C/SIGTERM/any error, never left blocked (procs.py)
        with worker_pool(n_workers, mp.get_context("fork")) as pool:
            parts = list(pool.map(_run_chunk, [a for a, _ in chunks], [b for _, b in chunks]))
    finally:
        _CTX = {}
    s = np.concatenate([p[0] for p in parts])
    info = merge_info([p[1] for p in parts], [p[0].size for p in parts])
    info["parallel_chunks"] = len(chunks)
    info["parallel_workers"] = n_workers
    xy = np.column_stack([np.concatenate([p[2][a] for p in parts]) for a in range(2)])
    return s, info, xy


def merge_info(infos: list[dict], sizes: list[int]) -> dict:
    """Sum counters, merge status counts, concatenate per-sample arrays of chunk infos."""
    out: dict = {}
    offset = 0
    for inf, size in zip(infos, sizes):
        for k, v in inf.items():
            if k == "window_status":
                d = out.setdefault(k, {})
                for kk, vv in v.items():
                    d[kk] = d.get(kk, 0) + vv
            elif k == "fallback_at_samples":
                out.setdefault(k, []).extend(int(x) + offset for x in v)
            elif isinstance(v, np.ndarray):
                out.setdefault(k, []).append(v)
            elif isinstance(v, list):
                out.setdefault(k, []).extend(v)
            elif k in ("horizon_samples", "n_window", "n_brake", "n_hold"):
                out[k] = v
            elif isinstance(v, (int, float)) and not isinstance(v, bool):
                out[k] = out.get(k, 0) + v
            else:
                out.setdefault(k, v)
        offset += size
    for k, v in list(out.items()):
        if isinstance(v, list) and v and isinstance(v[0], np.ndarray):
            out[k] = np.concatenate(v)
    out["fallback_at_samples"] = out.get("fallback_at_samples", [])[:100]
    return out
