"""The whole-trajectory twin (fast path) against the window-by-window twin (reference)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from gcode_feedopt.optimize.methods import make_twin_predictor
from gcode_feedopt.optimize.predictors import _causal_many, predict_trajectory
from gcode_feedopt.profile import load_profile


@pytest.fixture(scope="module")
def ender():
    return load_profile("ender3pro")


def _command(ts_s: float, n: int = 1500) -> np.ndarray:
    """(n, 2) XY: slow sweeps plus a square wave (steps excite every mode)."""
    t = np.arange(n) * ts_s
    return np.column_stack([50 + 20 * np.sin(2 * np.pi * 1.3 * t)
                            + 5 * np.sign(np.sin(2 * np.pi * 4 * t)),
                            80 + 15 * np.cos(2 * np.pi * 0.9 * t)])


def _windowed(tp, cmd, step=30):
    ref = copy.deepcopy(tp)
    for k in range(0, cmd.shape[0], step):
        ref.predict(k, cmd[k:k + step], jac=False)
        ref.commit(k, cmd[k:k + step])
    return np.array(ref.pred_mean), np.array(ref.pred_std)


@pytest.mark.parametrize("prior", ["physics", "feedback"])
def test_whole_trajectory_twin_equals_the_windowed_twin(ender, prior):
    """Offline (no measurements) the vectorized twin is the twin: same mean and std as
    committing 30 samples at a time, to 1e-9 mm — with the physics prior (error-feedback
    weights 0, so the self-predicted errors vanish) and with non-zero feedback weights and
    bias (the AR recursion of a learned prior)."""
    tp = make_twin_predictor(ender, "pidd", learn=False)
    if prior == "feedback":
        rng = np.random.default_rng(7)
        for a in range(2):
            tp.mu[a][2 + tp.n2:] = rng.normal(0.0, 0.02, tp.n3)
            tp.mu[a][0] = 0.003
    cmd = _command(ender.ts_s)
    m_ref, s_ref = _windowed(tp, cmd)
    m, s = predict_trajectory(tp, cmd)
    np.testing.assert_allclose(m, m_ref, atol=1e-9, rtol=0)
    np.testing.assert_allclose(s, s_ref, atol=1e-9, rtol=0)


def test_concatenated_windows_with_the_twins_memory_predict_their_own_samples(ender):
    """Windows cut from one trajectory, each with the twin's memory of history before it and
    the whole trajectory's reference, predicted in one call: every sample past a window's
    history equals the whole-trajectory prediction (the slow-down optimizer relies on it)."""
    tp = make_twin_predictor(ender, "pidd", learn=False)
    cmd = _command(ender.ts_s, 3000)
    whole_m, whole_s = predict_trajectory(tp, cmd)
    memory = max(h.size for h in tp.h) + tp.maxlag + 1
    spans = [(700, 1100), (1900, 2300), (2500, 3000)]
    idx = np.concatenate([np.arange(a - memory, b) for a, b in spans])
    m, s = predict_trajectory(tp, cmd[idx], ref=cmd[0])
    at = 0
    for a, b in spans:
        own = slice(at + memory, at + memory + (b - a))
        np.testing.assert_allclose(m[:, own], whole_m[:, a:b], atol=1e-9, rtol=0)
        np.testing.assert_allclose(s[:, own], whole_s[:, a:b], atol=1e-9, rtol=0)
        at += memory + (b - a)


@pytest.mark.parametrize("n_taps, sparse", [(500, False), (40, False), (700, True)])
def test_batched_causal_convolution_equals_numpy_convolve(n_taps, sparse):
    rng = np.random.default_rng(3)
    x = rng.normal(size=40_000)
    taps = rng.normal(size=(n_taps, 5))
    if sparse:
        taps[rng.random(n_taps) < 0.995] = 0.0
        taps[0] = 1.0
    got = _causal_many(x, taps)
    for j in range(taps.shape[1]):
        want = np.convolve(x, taps[:, j])[:x.size]
        np.testing.assert_allclose(got[j], want, atol=1e-9 * np.abs(want).max(), rtol=0)


def test_whole_benchy_prediction_is_a_fraction_of_the_print(ender):
    """Cost scales with samples, not windows: the vectorized twin over 20 k samples takes a
    small fraction of the windowed twin's time (ratio only; no absolute threshold)."""
    import time

    tp = make_twin_predictor(ender, "pidd", learn=False)
    cmd = _command(ender.ts_s, 6000)
    t0 = time.perf_counter()
    _windowed(tp, cmd[:1500])
    windowed = (time.perf_counter() - t0) * 4
    t0 = time.perf_counter()
    predict_trajectory(tp, cmd)
    whole = time.perf_counter() - t0
    assert whole < 0.2 * windowed

