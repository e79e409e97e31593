"""Predictors of the actual XY position over a window horizon, for mpc.py.

Each gives, for horizon commands cmd_h (n, 2) after the committed history, the predicted
actual position as mean (2, n), its Jacobian d mean/d cmd_h (2, n, n) (lower triangular:
causal) and a std (2, n):

- ``FirPredictor``: x̂ = x_0 + h * (x_c − x_0) with known impulse responses (the paper's
  Eq. 25, x̂ = Φ_c x_d + Φ_p x_c,past); optional known additive disturbance; zero std. With the
  plant's own impulse responses and effects it is the *oracle*.
- ``TwinPredictor``: the uncertainty-aware twin (paper Sec. 3.2) of each axis: features
  ψ_t = [1, x̂(t−n2…t), e(t−n3…t−1)], Bayesian weights β ~ N(μ, Σ) (Eq. 18/19), predictive
  mean μᵀψ_t and variance (blr.predict); unknown future errors e are the twin's own
  predictions (Eq. 5), so the mean is affine in the commands through a linear recursion.
  ``learn=True`` updates the weights from measurements as they arrive (online mode).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import toeplitz


def _fir_tail(h: np.ndarray, dev_hist: np.ndarray, dev_h: np.ndarray) -> np.ndarray:
    """(h * [dev_hist, dev_h]) at the horizon samples (n,), using only the last len(h)−1
    history samples."""
    nt = h.size
    n = dev_h.size
    past = dev_hist[-(nt - 1):] if nt > 1 else dev_hist[:0]
    seq = np.concatenate([past, dev_h])
    full = np.convolve(seq, h)[: seq.size]
    return full[past.size:past.size + n]


def _jac(h: np.ndarray, n: int) -> np.ndarray:
    col = np.zeros(n)
    m = min(n, h.size)
    col[:m] = h[:m]
    return np.tril(toeplitz(col))


class FirPredictor:
    """Known linear plant per axis (+ optional known disturbance d(k) (K?, 2) by sample)."""

    def __init__(self, h_x: np.ndarray, h_y: np.ndarray, *, disturbance=None, std_mm=0.0):
        self.h = (np.asarray(h_x, float), np.asarray(h_y, float))
        self.disturbance = disturbance  # callable k -> (m, 2)
        self.std = float(std_mm)
        self.cmd: list[np.ndarray] = []
        self._jac_cache: dict[int, np.ndarray] = {}

    def commit(self, k0: int, cmd: np.ndarray) -> None:
        self.cmd.extend(np.asarray(cmd, float))

    def predict(self, k0: int, cmd_h: np.ndarray):
        hist = np.asarray(self.cmd, float)
        ref = hist[0] if hist.size else cmd_h[0]
        n = cmd_h.shape[0]
        mean = np.empty((2, n))
        jac = np.empty((2, n, n))
        for a in range(2):
            mean[a] = ref[a] + _fir_tail(self.h[a], hist[:, a] - ref[a], cmd_h[:, a] - ref[a])
            key = (a, n)
            if key not in self._jac_cache:
                self._jac_cache[key] = _jac(self.h[a], n)
            jac[a] = self._jac_cache[key]
        if self.disturbance is not None:
            mean += self.disturbance(np.arange(k0, k0 + n)).T
        return mean, jac, np.full((2, n), self.std)
