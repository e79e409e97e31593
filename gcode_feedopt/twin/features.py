"""Predicted position of the physics model and the feature vectors ψ_t (paper Eqs. 2, 12, 13).

x̂(t) = x(0) + Σ_n h[n] (x_c(t−n) − x_c(0)): the convolution acts on the deviation from the
first commanded sample, so a machine at rest stays where it is whatever the DC truncation of h.
With h ~ N(μ_h, L Lᵀ), x̂(t) is Gaussian with mean μ_hᵀw_t and variance ||Lᵀw_t||², w_t the
window of past commands (full tap covariance; the paper's Eq. 12 keeps only the diagonal).

ψ_t = [1, x̂(t−n2·Ts), …, x̂(t), e(t−n3·Ts), …, e(t−Ts)] with e = x − x̂ (measured minus physics);
Σ_ψ is diagonal as in the paper's Eq. 13: var x̂ for the x̂ terms and for the e terms (x is
measured, so e inherits x̂'s uncertainty).
"""

from __future__ import annotations

import numpy as np
from scipy.signal import oaconvolve

from .frf import ImpulseResponse


def xhat(ir: ImpulseResponse, x_cmd: np.ndarray, *, with_var: bool = True,
         diagonal_only: bool = False):
    """Mean (T,) and variance (T,) of the physics-model position for commanded x_cmd (T,).

    ``diagonal_only`` gives the paper's Eq. 12 variance Σ σ_h[n]² w_t[n]² (for comparison)."""
    x0 = float(x_cmd[0])
    w = np.asarray(x_cmd, float) - x0
    T = w.size
    mean = x0 + oaconvolve(w, ir.mean)[:T]
    if not with_var:
        return mean, None
    if diagonal_only:
        return mean, oaconvolve(w * w, ir.var)[:T]
    L = ir.factor
    if L.shape[1] == 0:
        return mean, np.zeros(T)
    var = np.zeros(T)
    # chunk the columns to bound memory (T × chunk floats)
    chunk = max(1, int(2e7 // max(T, 1)))
    for j in range(0, L.shape[1], chunk):
        Y = oaconvolve(w[None, :], L[:, j:j + chunk].T, axes=1)[:, :T]
        var += np.einsum("ij,ij->j", Y, Y)
    return mean, var


def factor_series(ir: ImpulseResponse, w: np.ndarray) -> np.ndarray:
    """(r, T) Y with x̂(t) − E x̂(t) = Y[:, t]ᵀ z, z ~ N(0, I_r): the random part of the
    predicted position for command deviations w (T,). cov(x̂(t), x̂(u)) = Y[:, t] · Y[:, u]."""
    L = ir.factor
    T = w.size
    if L.shape[1] == 0:
        return np.zeros((0, T))
    return oaconvolve(w[None, :], L.T, axes=1)[:, :T]


def n_features(n2: int, n3: int) -> int:
    return 1 + (n2 + 1) + n3


def lagged(a: np.ndarray, lag: int, fill: float) -> np.ndarray:
    """a(t − lag), with ``fill`` before the start."""
    if lag == 0:
        return a
    out = np.empty_like(a)
    out[:lag] = fill
    out[lag:] = a[:-lag]
    return out


def feature_matrix(xhat_mean, xhat_var, e, n2: int, n3: int):
    """Ψ mean (T, d) and variance (T, d) for a whole trajectory.

    Args:
        xhat_mean, xhat_var: (T,) physics-model position and its variance.
        e: (T,) errors x − x̂ (measured minus physics) or, where not measured, their
            predictions; e(t) enters ψ_{t+1} … ψ_{t+n3}.
    """
    T = xhat_mean.size
    d = n_features(n2, n3)
    M = np.empty((T, d))
    V = np.zeros((T, d))
    M[:, 0] = 1.0
    x0 = float(xhat_mean[0])
    for j in range(n2 + 1):  # columns 1..n2+1: x̂(t-n2) ... x̂(t)
        lag = n2 - j
        M[:, 1 + j] = lagged(xhat_mean, lag, x0)
        V[:, 1 + j] = lagged(xhat_var, lag, 0.0)
    for j in range(n3):  # e(t-n3) ... e(t-1)
        lag = n3 - j
        M[:, 2 + n2 + j] = lagged(e, lag, 0.0)
        V[:, 2 + n2 + j] = lagged(xhat_var, lag, 0.0)
    return M, V


def physics_prior(n2: int, n3: int, *, var_xhat: float = 1e-8, var_e: float | None = None,
                  var_bias: float = 1e-8):
    """The prior that reproduces the physics model: β = e_{x̂(t)} (weight 1 on the current
    x̂, 0 elsewhere) with independent variances (used when a profile has no learned prior).

    Scales (features are deviations from the start, so a weight error on x̂ costs that error
    times the distance travelled): x̂ weights ±1e-4 (5 µm over 50 mm — the physics is trusted
    there, its uncertainty is already in Σ_ψ); error-feedback weights ±1/n3 each, so their sum
    — a full-strength feedback of the last errors — is within one σ (±1/√n3 each would make the
    first second of predictions ten times too cautious); bias ±1 µm: in these coordinates the
    machine starts where it was commanded (a position axis at rest sits at its command): ±0.1 µm;
    wider bias prior widened every interval by itself (±0.01 mm made the CLI's 95 % interval
    hold 99.99 % of a log whose error was 1.8 µm); data move it at once where it is real."""
    d = n_features(n2, n3)
    mu = np.zeros(d)
    mu[1 + n2] = 1.0
    var = np.full(d, var_xhat)
    var[0] = var_bias
    var[2 + n2:] = (1.0 / max(n3, 1) ** 2) if var_e is None else var_e
    return mu, np.diag(var)


#: Prior std of the *sum* of the x̂ weights (the physics model's DC gain): stepper axes
#: position by counting steps, and every FRF draw keeps the certain DC gain (twin.frf).
DC_GAIN_STD = 1e-6


def shift_invariant_cov(cov: np.ndarray, n2: int, dc_std: float = DC_GAIN_STD) -> np.ndarray:
    """Prior covariance of β with the x̂-weight block made shift-invariant.

    The features are deviations from the first commanded sample, so with independent x̂
    weights (physics_prior: σ = 1e-4 each) the predictive variance grows as
    Σ_j σ² x̂_j² with the distance from the start: 177 mm from the origin it is 0.058 mm,
    more than half of a 0.1 mm tolerance, for a machine whose DC gain is certain. We keep
    the stated uncertainty on the *shape* of the weights (differences, which act on the
    motion) and give their sum — a gain error, the only part a translation sees — the std
    ``dc_std``: Σ' = P Σ P + dc_std² 11ᵀ/m² on the x̂ block, P = I − 11ᵀ/m, so that
    Var(1ᵀβ) = dc_std² (an earlier version added dc_std² 11ᵀ, a sum std of m·dc_std: 11 µm
    per 1 m of travel instead of 1 µm)."""
    cov = np.array(cov, float)
    idx = np.arange(1, 2 + n2)
    m = idx.size
    one = np.full((m, 1), 1.0 / np.sqrt(m))
    P = np.eye(m) - one @ one.T
    full_P = np.eye(cov.shape[0])
    full_P[np.ix_(idx, idx)] = P
    out = full_P @ cov @ full_P.T
    out[np.ix_(idx, idx)] += dc_std ** 2 * (one @ one.T) / m  # = dc_std² 11ᵀ/m²
    return 0.5 * (out + out.T)
