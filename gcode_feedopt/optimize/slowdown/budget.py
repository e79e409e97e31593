"""The stringency as the share of samples within tolerance (optimize.slowdown, step 4).

The paper's chance constraint holds on every sample: P(|e_k| ≤ E_max) ≥ η, i.e. the bound
|μ_k| + Φ⁻¹(η)σ_k ≤ E_max. The product's stringency is what is judged: η of the samples within
E_max, and RMS γ (the excess over E_max, 0 within) at most (1 − η)·E_max, the paper's own rule
for the conservative plan. The per-sample constraint implies both in expectation, but spends
the whole margin Φ⁻¹(η)σ on every sample, most of which are nowhere near the tolerance; their
risk is spent for nothing. Here the risk is allocated (Ono & Williams' risk allocation for
joint chance constraints): a sample whose bound exceeds E_max while its mean stays within
(|μ| ≤ E_max < |μ| + zσ) is left as it is while the expected share of samples out of
tolerance, summed over every constrained sample under the twin's Gaussian prediction,
stays within ``share``·(1 − η), and the expected mean square γ within (``share``·(1 − η)·E_max)²
(each sample's γ taken relative to its own E_max, so per-feature tolerances weigh alike).
``share`` < 1 keeps the rest of the stringency's room for what the twin does not know. A
sample whose mean is beyond E_max — more likely out than in — is never left.

Closed forms, e ~ N(μ, σ²) across the path (μ ≥ 0 the motion part of the bound):
P(|e| > E) = Φ((μ − E)/σ) + Φ((−μ − E)/σ);
E[(X − c)₊²] = ((m − c)² + s²)Φ(d) + (m − c)s φ(d), d = (m − c)/s, for X ~ N(m, s²), taken
for both tails. (tests/optimize/test_budget.py checks them by Monte Carlo.)"""

from __future__ import annotations

import numpy as np
from scipy.special import ndtr

_SQRT_2PI = np.sqrt(2.0 * np.pi)
#: beyond this many σ inside the tolerance a sample's tail is below 1e-15: not computed
_FAR = 8.0


def _upper(m, s, c):
    """E[(X − c)₊²] and P(X > c) for X ~ N(m, s²), elementwise."""
    d = (m - c) / s
    p = ndtr(d)
    return ((m - c) ** 2 + s * s) * p + (m - c) * s * np.exp(-0.5 * d * d) / _SQRT_2PI, p


def tail_moments(mu, sd, tol):
    """P(|e| > tol) and E[γ²], γ = max(|e| − tol, 0), of e ~ N(mu, sd²), elementwise
    (sd > 0, tol > 0 finite; mm or any unit)."""
    mu, sd, tol = np.broadcast_arrays(*(np.asarray(a, float) for a in (mu, sd, tol)))
    g_hi, p_hi = _upper(mu, sd, tol)
    g_lo, p_lo = _upper(-mu, sd, tol)
    return p_hi + p_lo, g_hi + g_lo


def beyond_budget(viol, mot, sd, tol, on, eta: float, share: float) -> np.ndarray:
    """The violations ``viol`` (indices, bound over tolerance) that the stringency's budget
    cannot carry (module docstring): those with the mean beyond tolerance, and of the rest
    those left over once the cheapest (lowest probability out) fill the budget.

    ``mot``, ``sd`` (K,): the motion part of the bound and σ across the path, mm; ``tol``:
    E_max, scalar or (K,) (inf: not constrained); ``on`` (K,) bool: the constrained samples.
    """
    viol = np.asarray(viol)
    if viol.size == 0 or share <= 0.0 or not 0.0 < eta < 1.0:
        return viol
    tol_k = np.broadcast_to(np.asarray(tol, float), mot.shape)
    fin = on & np.isfinite(tol_k) & (sd > 0)
    n = int(np.count_nonzero(fin))
    if n == 0:
        return viol
    soft = fin[viol] & (mot[viol] <= tol_k[viol])
    cand = viol[soft]
    if cand.size == 0:
        return viol
    # every constrained sample within its bound: its expected share out and γ² (the
    # candidates' own are added in order below; those with the mean beyond are being slowed
    # down); far inside the tolerance they are nil
    other = fin.copy()
    other[viol] = False
    near = np.flatnonzero(other & (mot + _FAR * sd > tol_k))
    p0, g0 = tail_moments(mot[near], sd[near], tol_k[near])
    base_p = float(np.sum(p0))
    base_g = float(np.sum(g0 / tol_k[near] ** 2))
    pc, gc = tail_moments(mot[cand], sd[cand], tol_k[cand])
    gc = gc / tol_k[cand] ** 2
    order = np.argsort(pc, kind="stable")
    room_p = share * (1.0 - eta) * n
    room_g = (share * (1.0 - eta)) ** 2 * n
    fits = ((base_p + np.cumsum(pc[order]) <= room_p)
            & (base_g + np.cumsum(gc[order]) <= room_g))
    # the longest prefix that fits (cumulative sums only grow)
    k = int(np.argmin(fits)) if not fits.all() else fits.size
    keep = np.ones(viol.size, bool)
    keep[np.flatnonzero(soft)[order[:k]]] = False
    return viol[keep]


def left_over(viol, out: dict, tol, z: float, share: float) -> np.ndarray:
    """:func:`beyond_budget` of an evaluated slow-down plan: ``out`` its fields (``b`` the
    bound, ``mot`` its motion part, ``unc`` = zσ), ``z`` = Φ⁻¹(η) of its evaluator. Every
    violation is left over without a budget (``share`` 0) or a stringency (z ≤ 0); an evaluator
    without uncertainty (the oracle) has nothing to carry."""
    if share <= 0.0 or z <= 0.0:
        return viol
    return beyond_budget(viol, out["mot"], out["unc"] / z, tol, out["b"] > 0.0, float(ndtr(z)),
                         share)


def expected_share(mot, sd, tol, on):
    """(expected share of the constrained samples out of tolerance, expected RMS γ mm) of a
    plan under the twin's Gaussian prediction (sd 0: the motion part is exact)."""
    tol_k = np.broadcast_to(np.asarray(tol, float), mot.shape)
    fin = on & np.isfinite(tol_k)
    n = int(np.count_nonzero(fin))
    if n == 0:
        return 0.0, 0.0
    exact = fin & (sd <= 0)
    p = float(np.sum(mot[exact] > tol_k[exact]))
    g = float(np.sum(np.maximum(mot[exact] - tol_k[exact], 0.0) ** 2))
    near = np.flatnonzero(fin & (sd > 0) & (mot + _FAR * sd > tol_k))
    pn, gn = tail_moments(mot[near], sd[near], tol_k[near])
    return (p + float(np.sum(pn))) / n, float(np.sqrt((g + float(np.sum(gn))) / n))
