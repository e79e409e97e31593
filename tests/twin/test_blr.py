"""Bayesian regression with uncertain inputs: derivatives, posterior, recovery, agreement."""

import numpy as np
import pytest

from gcode_feedopt.twin.blr import (BayesianRegressor, conjugate_update, grad_hess, laplace_update,
                                    loglik, predict, rls_init, rls_update)


def case(n=4, seed=0):
    rng = np.random.default_rng(seed)
    beta = rng.normal(size=n)
    mu = rng.normal(size=n)
    var = rng.uniform(0.01, 0.3, n)
    return rng, beta, mu, var


def test_gradient_and_hessian_against_finite_differences():
    rng, beta, mu, var = case()
    x, s2 = 1.3, 0.05
    g, H = grad_hess(beta, mu, var, x, s2)
    eps = 1e-6
    g_fd = np.array([(loglik(beta + eps * e, mu, var, x, s2) - loglik(beta - eps * e, mu, var, x, s2))
                     / (2 * eps) for e in np.eye(beta.size)])
    H_fd = np.array([(grad_hess(beta + eps * e, mu, var, x, s2)[0]
                      - grad_hess(beta - eps * e, mu, var, x, s2)[0]) / (2 * eps)
                     for e in np.eye(beta.size)])
    np.testing.assert_allclose(g, g_fd, rtol=1e-6, atol=1e-8)
    np.testing.assert_allclose(H, H_fd, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(H, H.T, atol=1e-12)


@pytest.mark.parametrize("curv", ["moment", "fisher", "hessian"])
def test_deterministic_features_reduce_to_eq19(curv):
    rng, beta, mu, var = case()
    m0, C0 = np.zeros(4), np.eye(4)
    a = laplace_update(m0, C0, mu, np.zeros(4), 0.7, 0.01, curv)
    b = conjugate_update(m0, C0, mu, 0.7, 0.01)
    np.testing.assert_allclose(a[0], b[0], atol=1e-10)
    np.testing.assert_allclose(a[1], b[1], atol=1e-10)


def test_full_one_step_laplace_overshoots_where_moment_form_does_not():
    """Documented reason for the default: the paper's full expansion diverges on a stream."""
    rng = np.random.default_rng(5)
    n = 6
    beta_true = rng.normal(size=n)
    runs = {}
    for curv in ("moment", "fisher"):
        m, C = np.zeros(n), 10 * np.eye(n)
        r2 = np.random.default_rng(6)
        for _ in range(300):
            mu = r2.normal(size=n)
            x = beta_true @ (mu + 1e-2 * r2.normal(size=n)) + 1e-2 * r2.normal()
            m, C = laplace_update(m, C, mu, np.full(n, 1e-4), x, 1e-4, curv)
        runs[curv] = np.abs(m - beta_true).max()
    assert runs["moment"] < 0.05
    assert runs["fisher"] > 10 * runs["moment"]


def test_laplace_matches_monte_carlo_posterior():
    """Small case: prior N(m0, C0), 20 samples with uncertain inputs; compare the sequential
    Laplace posterior with an importance-sampled exact posterior."""
    rng = np.random.default_rng(4)
    n, s2 = 2, 0.02
    beta_true = np.array([0.5, -0.8])
    m0, C0 = np.zeros(n), 0.5 * np.eye(n)
    data = []
    for _ in range(20):
        mu = rng.normal(size=n)
        var = np.full(n, 0.02)
        psi = mu + np.sqrt(var) * rng.normal(size=n)
        x = beta_true @ psi + np.sqrt(s2) * rng.normal()
        data.append((mu, var, x))
    m, C = m0.copy(), C0.copy()
    for mu, var, x in data:
        m, C = laplace_update(m, C, mu, var, x, s2)
    # importance sampling from the prior
    B = rng.multivariate_normal(m0, C0, size=400_000)
    logw = np.zeros(B.shape[0])
    for mu, var, x in data:
        s = (B * B) @ var + s2
        r = x - B @ mu
        logw += -0.5 * r * r / s - 0.5 * np.log(s)
    w = np.exp(logw - logw.max())
    w /= w.sum()
    mc_mean = w @ B
    mc_cov = (B - mc_mean).T @ ((B - mc_mean) * w[:, None])
    np.testing.assert_allclose(m, mc_mean, atol=0.05)
    np.testing.assert_allclose(np.sqrt(np.diag(C)), np.sqrt(np.diag(mc_cov)), rtol=0.25)


def test_regression_recovers_planted_weights():
    rng = np.random.default_rng(5)
    n, s2 = 6, 1e-4
    beta_true = rng.normal(size=n)
    reg = BayesianRegressor(mu=np.zeros(n), cov=10 * np.eye(n), sigma2=s2)
    for _ in range(2000):
        mu = rng.normal(size=n)
        var = np.full(n, 1e-4)
        x = beta_true @ (mu + 1e-2 * rng.normal(size=n)) + 1e-2 * rng.normal()
        reg.update(mu, var, x)
    np.testing.assert_allclose(reg.mu, beta_true, atol=0.02)
    # posterior variance never grows with more data (Fisher update is a PSD downdate)
    v0 = np.diag(reg.cov).copy()
    reg.update(rng.normal(size=n), np.full(n, 1e-4), 0.3)
    assert np.all(np.diag(reg.cov) <= v0 + 1e-15)


def test_pure_and_stateful_agree():
    rng, beta, mu, var = case(seed=9)
    m, C = np.zeros(4), np.eye(4)
    reg = BayesianRegressor(mu=m.copy(), cov=C.copy(), sigma2=0.01)
    for k in range(30):
        p = rng.normal(size=4)
        x = float(beta @ p)
        m, C = laplace_update(m, C, p, var, x, 0.01)
        reg.update(p, var, x)
    np.testing.assert_allclose(reg.mu, m, atol=1e-12)
    np.testing.assert_allclose(reg.cov, C, atol=1e-12)
    a = predict(m, C, mu, var, 0.01)
    b = reg.predict(mu, var)
    assert a[0] == pytest.approx(b[0], abs=1e-12) and a[1] == pytest.approx(b[1], abs=1e-12)


def test_predictive_variance_against_monte_carlo():
    rng, beta, mu, var = case(seed=2)
    C = 0.05 * np.eye(4)
    m = beta
    mean, v = predict(m, C, mu, var, 0.01)
    B = rng.multivariate_normal(m, C, 200_000)
    P = mu + np.sqrt(var) * rng.normal(size=(200_000, 4))
    xs = np.einsum("ij,ij->i", B, P) + 0.1 * rng.normal(size=200_000)
    assert xs.mean() == pytest.approx(mean, abs=0.01)
    assert xs.var() == pytest.approx(v, rel=0.02)


def test_rls_with_forgetting_tracks_a_change():
    rng = np.random.default_rng(1)
    b1, b2 = np.array([1.0, 2.0]), np.array([-1.0, 0.5])
    psi = rng.normal(size=2)
    beta, P = rls_init(psi, float(b1 @ psi), 1e-3)
    for k in range(600):
        psi = rng.normal(size=2)
        target = b1 if k < 300 else b2
        beta, P = rls_update(beta, P, psi, float(target @ psi), 0.95)
    np.testing.assert_allclose(beta, b2, atol=1e-4)  # old data weighs 0.95^300


def test_appendix_a_prior_fits_the_measured_machines():
    from gcode_feedopt.profile import load_profile
    from gcode_feedopt.twin.features import physics_prior
    from gcode_feedopt.twin.physics import axis_impulse, member_impulses
    from gcode_feedopt.twin.prior import init_prior

    prof = load_profile("ender3pro")
    mu, cov, rec = init_prior(axis_impulse(prof, "y"), member_impulses(prof, "y"), prof.ts_s,
                              10, 30, 0.01)
    assert rec["converged"]
    mu0, cov0 = physics_prior(10, 30)
    # the x̂ weights still sum to ~1 (the DC gain), and the spread is not degenerate
    assert abs(mu[1:12].sum() - 1.0) < 0.05
    assert cov[1, 1] > 0 and np.all(np.isfinite(cov))
    # the machines' mean response is the twin's mean (both from the same modal fits), so the
    # maximum-likelihood weights are the physics prior's; the spread goes into the variance
    np.testing.assert_allclose(mu, mu0, atol=1e-6)
    assert cov[1, 1] != cov0[1, 1]
