"""The stringency's budget of the slow-down (optimize.slowdown.budget): closed forms against
Monte Carlo, and which violations the budget carries."""

import numpy as np
import pytest

from gcode_feedopt.optimize.slowdown.budget import beyond_budget, expected_share, tail_moments


@pytest.mark.parametrize("mu,sd,tol", [(0.0, 0.01, 0.02), (0.045, 0.01, 0.05),
                                       (0.06, 0.02, 0.05), (0.01, 0.03, 0.02)])
def test_tail_moments_match_monte_carlo(mu, sd, tol):
    rng = np.random.default_rng(7)
    e = rng.normal(mu, sd, 2_000_000)
    gamma = np.maximum(np.abs(e) - tol, 0.0)
    p, g2 = tail_moments(mu, sd, tol)
    p_mc, g2_mc = np.mean(gamma > 0), np.mean(gamma ** 2)
    # 2e6 draws: the standard errors are well under 1 % of these values
    assert p == pytest.approx(p_mc, rel=0.02, abs=1e-5)
    assert g2 == pytest.approx(g2_mc, rel=0.02, abs=1e-12)


def test_expected_share_is_the_mean_of_the_tails():
    mot = np.array([0.0, 0.04, 0.05, 0.07, 0.2])
    sd = np.array([0.01, 0.01, 0.01, 0.0, 0.01])
    on = np.array([True, True, True, True, False])
    p_out, rms = expected_share(mot, sd, 0.05, on)
    p, g = tail_moments(mot[:3], sd[:3], 0.05)
    # the fourth is exact (σ 0): out by 0.02 mm; the fifth is not constrained
    assert p_out == pytest.approx((p.sum() + 1.0) / 4)
    assert rms == pytest.approx(np.sqrt((g.sum() + 0.02 ** 2) / 4))


def test_budget_carries_the_cheapest_soft_violations_only():
    n = 1000
    mot = np.full(n, 0.01)
    sd = np.full(n, 0.01)
    tol = 0.05
    on = np.ones(n, bool)
    # ten samples over their bound (0.045 + 1.28·0.01 > 0.05) with the mean within, in order
    # of cost, and two with the mean beyond the tolerance
    soft = np.arange(10)
    mot[soft] = np.linspace(0.040, 0.049, 10)
    mot[[10, 11]] = 0.051
    viol = np.arange(12)
    eta = 0.9
    left = beyond_budget(viol, mot, sd, tol, on, eta, share=1.0)
    # a mean beyond the tolerance is never carried
    assert {10, 11} <= set(left.tolist())
    # the room: 100 samples' worth of expected share out: all ten soft ones fit
    assert set(left.tolist()) == {10, 11}
    # a small budget (η 0.995: 5 samples out of 1000, RMS γ 0.5 % of E_max): the
    # cheapest ones only, as long as both the expected share out and γ² fit
    eta2 = 0.995
    left = beyond_budget(viol, mot, sd, tol, on, eta2, share=1.0)
    p0, g0 = tail_moments(mot[12:], sd[12:], tol)
    p, g = tail_moments(mot[soft], sd[soft], tol)
    fits = ((p0.sum() + np.cumsum(p) <= (1 - eta2) * n)
            & ((g0.sum() + np.cumsum(g)) / tol ** 2 <= (1 - eta2) ** 2 * n))
    k = int(np.argmin(fits))
    assert 0 < k < 10 and not fits[k:].any()
    assert set(left.tolist()) == set(range(k, 12))
    # share 0: the paper's per-sample constraint
    assert beyond_budget(viol, mot, sd, tol, on, eta, share=0.0).tolist() == viol.tolist()


def test_budget_counts_the_samples_within_their_bound_too():
    """Samples within their bound still spend the budget: a plan whose every sample sits at
    its bound already expects 1 − η of them out, and carries nothing more."""
    n, eta, tol, sd = 500, 0.9, 0.05, 0.01
    z = 1.2815515655446004
    mot = np.full(n, tol - z * sd)  # every bound exactly at E_max
    mot[:3] = tol - 0.5 * sd        # three over their bound, the mean within
    on = np.ones(n, bool)
    left = beyond_budget(np.arange(3), mot, np.full(n, sd), tol, on, eta, share=1.0)
    assert left.tolist() == [0, 1, 2]
