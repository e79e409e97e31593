"""The diagnosis's small numerical cores against closed forms: the bounded fit of the plant
draw (a trust-region subproblem with a ridge) and the effective sample count of a coloured
residual."""

import numpy as np
import pytest

from gcode_feedopt.closedloop.catalogue import _n_eff
from gcode_feedopt.closedloop.diagnose import _solve_bounded


def _problem(seed):
    rng = np.random.default_rng(seed)
    p = int(rng.integers(2, 13))
    nz = int(rng.integers(1, p + 1))
    X = rng.normal(size=(300, p)) * np.exp(2.0 * rng.normal(size=p))
    y = 10.0 * rng.normal(size=300)
    return X.T @ X, X.T @ y, nz, float(abs(rng.normal()) * 0.3), float(abs(rng.normal()))


@pytest.mark.parametrize("seed", range(40))
def test_the_bounded_fit_meets_its_optimality_conditions(seed):
    """argmin ‖y − Xθ‖² + λ0‖θ_z‖² with ‖θ_z‖ ≤ r (θ_z = θ[:nz]): inside the ball the ridge
    normal equations hold; on it, (A + (λ0 + μ) D) θ = b with μ ≥ 0 (KKT), i.e. the free
    block's gradient vanishes and the bounded block's is −(λ0 + μ) θ_z."""
    A, b, nz, r, lam0 = _problem(seed)
    th = _solve_bounded(A, b, nz, r, lam0)
    z = th[:nz]
    g = A @ th - b
    scale = np.linalg.norm(b)
    assert np.linalg.norm(g[nz:]) < 1e-6 * scale
    if np.linalg.norm(z) < r * (1 - 1e-6):
        np.testing.assert_allclose(g[:nz], -lam0 * z, atol=1e-6 * scale)
        return
    assert abs(np.linalg.norm(z) - r) < 1e-6 * r
    lam = -float(g[:nz] @ z) / float(z @ z)
    assert lam >= lam0 * (1 - 1e-6)
    np.testing.assert_allclose(g[:nz], -lam * z, atol=1e-5 * np.linalg.norm(g[:nz]) + 1e-9)


def test_a_bound_that_does_not_bind_is_the_ridge_fit():
    A, b, nz, _, lam0 = _problem(7)
    D = np.r_[np.ones(nz), np.zeros(A.shape[0] - nz)]
    want = np.linalg.solve(A + np.diag(D * lam0), b)
    np.testing.assert_allclose(_solve_bounded(A, b, nz, np.inf, lam0), want, rtol=1e-8)


def _n_eff_direct(r):
    """The same sum with the autocorrelation summed lag by lag (O(n²))."""
    x = r - r.mean()
    n = x.size
    c0 = float(x @ x)
    s = 0.0
    for k in range(1, min(n - 1, 2000)):
        rho = float(x[:-k] @ x[k:]) / c0
        if rho <= 0:
            break
        s += rho
    return max(n / (1 + 2 * s), 2.0)


@pytest.mark.parametrize("n", [97, 500, 1999, 3001])
def test_the_effective_sample_count_is_the_autocorrelation_sum(n):
    """N / (1 + 2 Σ ρ_k) over the initial positive sequence, whatever the length (the FFT is
    padded to a fast size), and an AR(1)'s N (1 − φ) / (1 + φ) on a long series."""
    rng = np.random.default_rng(n)
    e = rng.normal(size=n)
    x = np.empty(n)
    x[0] = e[0]
    for k in range(1, n):
        x[k] = 0.8 * x[k - 1] + e[k]
    assert _n_eff(x) == pytest.approx(_n_eff_direct(x), rel=1e-9)
    if n > 1000:
        assert _n_eff(x) == pytest.approx(n * 0.2 / 1.8, rel=0.35)
