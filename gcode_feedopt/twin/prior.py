"""Prior of the regression weights by maximum likelihood on a trial trajectory (Appendix A).

The paper fits (μ_β, Σ_β) by maximising Σ_t ln N(x_trial(t); μ_βᵀψ_t, ψ_tᵀΣ_βψ_t + σ²) with
deterministic features (ψ3 = 0) on a conservative trial trajectory whose "measurement" is the
nominal model's own output, x_trial ≈ x̂_trial. That data set is fitted exactly by μ_β = e_{x̂(t)},
so its MLE of Σ_β is zero — a prior a twin can never learn from. We keep the method and give it
data that carries the known uncertainty: the trial trajectory filtered by **each of the N_H
measured FRFs** (not only by their mean), so Σ_β is the spread of weights the measured machines
need. Σ_β is diagonal with one variance per block (bias, x̂ weights), fitted in log space; the
error-feedback weights are not identifiable from ψ3 = 0 and keep the physics prior's variance.

``init_prior`` returns (μ, Σ, record). The built-in profiles do not store it by default: with the
plant draw learned as a latent variable (model.py), the FRF spread is already in the twin once,
and a prior fitted to the same spread would count it twice (see docs/twin.md §6).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize
from scipy.signal import oaconvolve

from .features import feature_matrix, n_features, physics_prior, xhat
from .frf import ImpulseResponse


def trial_trajectory(ts_s: float, amp_mm: float = 20.0, vmax_mm_s: float = 30.0,
                     amax_mm_s2: float = 1000.0, n_moves: int = 12) -> np.ndarray:
    """A conservative back-and-forth trial motion (rest-to-rest trapezoids of growing length),
    (T,) positions, mm."""
    x, out = 0.0, [0.0]
    rng = np.random.default_rng(0)
    for k in range(n_moves):
        d = amp_mm * (0.2 + 0.8 * (k + 1) / n_moves) * (1 if k % 2 == 0 else -1)
        v = vmax_mm_s * (0.5 + 0.5 * rng.random())
        L = abs(d)
        ta = v / amax_mm_s2
        if L < v * ta:
            v = np.sqrt(L * amax_mm_s2)
            ta = v / amax_mm_s2
        T = L / v + ta
        t = np.arange(1, int(np.ceil(T / ts_s)) + 1) * ts_s
        s = np.where(t < ta, 0.5 * amax_mm_s2 * t * t,
                     np.where(t < T - ta, 0.5 * v * ta + v * (t - ta),
                              L - 0.5 * amax_mm_s2 * np.clip(T - t, 0, None) ** 2))
        out.extend(x + np.sign(d) * np.clip(s, 0, L))
        x += d
        out.extend([x] * int(0.2 / ts_s))  # settle
    return np.asarray(out)


def init_prior(ir: ImpulseResponse, hs: np.ndarray, ts_s, n2, n3, sigma_eps_mm, *,
               max_samples: int = 3000):
    """(μ_β, Σ_β, record) by maximum likelihood on the trial trajectory (module docstring).

    ``ir``: the axis's Gaussian impulse response; ``hs`` (N_H, n_taps): each measured FRF's
    own response (``twin.physics.axis_impulse`` / ``member_impulses``)."""
    x_d = trial_trajectory(ts_s)
    xm, _ = xhat(ir, x_d, with_var=False)
    xm = xm - x_d[0]
    M, _ = feature_matrix(xm, np.zeros_like(xm), np.zeros_like(xm), n2, n3)
    w = x_d - x_d[0]
    step = max(1, len(x_d) // max_samples)
    idx = np.arange(0, len(x_d), step)
    Psi = np.vstack([M[idx]] * hs.shape[0])
    X = np.concatenate([oaconvolve(w, h)[:len(w)][idx] for h in hs])
    d = n_features(n2, n3)
    mu0, cov0 = physics_prior(n2, n3)
    xcols = slice(1, 2 + n2)
    s2 = sigma_eps_mm ** 2

    def unpack(p):
        mu = mu0.copy()
        mu[0] = p[0]
        mu[xcols] = p[1:2 + n2]
        var = np.diag(cov0).copy()
        var[0] = np.exp(p[-2])
        var[xcols] = np.exp(p[-1])
        return mu, var

    def nll(p):
        mu, var = unpack(p)
        m = Psi @ mu
        s = (Psi * Psi) @ var + s2
        r = X - m
        return 0.5 * np.sum(r * r / s + np.log(s))

    p0 = np.concatenate([[0.0], mu0[xcols], [np.log(cov0[0, 0]), np.log(cov0[1, 1])]])
    res = minimize(nll, p0, method="L-BFGS-B")
    mu, var = unpack(res.x)
    record = {"method": "maximum likelihood, Appendix A, on a trial trajectory filtered by each "
                        f"of the {hs.shape[0]} measured FRFs", "samples": int(len(X)),
              "converged": bool(res.success), "nll": float(res.fun)}
    return mu, np.diag(var), record
