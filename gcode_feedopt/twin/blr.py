"""Learning the unknown uncertainty: Bayesian linear regression with uncertain inputs
(Laplace approximation, paper Eqs. 14–18 and Appendix B), its deterministic-feature special
case (Eq. 19), and recursive least squares with forgetting (Sec. 3.1, Eqs. 3–4).

Model of one sample (paper Eq. 7): x = βᵀψ + ε with ψ ~ N(μ_ψ, Σ_ψ) (Σ_ψ diagonal, as the
paper's Eq. 13), β ~ N(μ_β, Σ_β), ε ~ N(0, σ²). Given β, the marginal likelihood of x is

    p(x | β) = N(x; βᵀμ_ψ, s(β)),   s(β) = βᵀΣ_ψβ + σ².

We keep the normaliser −½ ln s(β) that the paper's Eq. 15 leaves out: it depends on β, and
without it the likelihood rewards inflating βᵀΣ_ψβ. Writing r = x − βᵀμ_ψ (derivation in
docs/twin.md, checked against finite differences in the tests):

    ∇ℓ = r μ_ψ / s + (r²/s² − 1/s) Σ_ψβ
    ∇²ℓ = −μ_ψμ_ψᵀ/s − (2r/s²)(μ_ψβᵀΣ_ψ + Σ_ψβμ_ψᵀ) + (2/s² − 4r²/s³) Σ_ψββᵀΣ_ψ + (r²/s² − 1/s) Σ_ψ

The Laplace step expands ℓ about β̄ = μ_β (the prior mean, as the paper does). Two things go
wrong with the full expansion of a single sample, and the tests show both: the observed Hessian
is indefinite whenever r² > s (its last term), so the "posterior covariance" need not be
positive definite; and the variance gradient (r²/s² − 1/s)Σ_ψβ̄ pushes β outward — to explain a
large residual by inflating βᵀΣ_ψβ — with a step that a one-sided expansion cannot bound, so a
sequence of updates diverges. The default (``moment``) therefore holds s at β̄: the update is
then exact for the Gaussian p(x|β) ≈ N(βᵀμ_ψ, s(β̄)), carries the feature (known) uncertainty as
inflated noise, is O(n²) and never increases any posterior variance. ``fisher`` (expected
negative Hessian, PSD, rank two) and ``hessian`` (observed, with a Fisher fallback) keep the
paper's full expansion for comparison. With Σ_ψ = 0 all three reduce exactly to Eq. 19.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def loglik(beta, psi_mu, psi_var, x, sigma2):
    """ln p(x | β) of one sample (with its normaliser, without the constant)."""
    s = float(beta @ (psi_var * beta)) + sigma2
    r = x - float(beta @ psi_mu)
    return -0.5 * r * r / s - 0.5 * np.log(s)


def grad_hess(beta, psi_mu, psi_var, x, sigma2):
    """Gradient (n,) and Hessian (n, n) of :func:`loglik` with respect to β."""
    Sb = psi_var * beta
    s = float(beta @ Sb) + sigma2
    r = x - float(beta @ psi_mu)
    g = r * psi_mu / s + (r * r / s ** 2 - 1.0 / s) * Sb
    H = (-np.outer(psi_mu, psi_mu) / s
         - (2 * r / s ** 2) * (np.outer(psi_mu, Sb) + np.outer(Sb, psi_mu))
         + (2 / s ** 2 - 4 * r * r / s ** 3) * np.outer(Sb, Sb)
         + (r * r / s ** 2 - 1.0 / s) * np.diag(psi_var))
    return g, H


def laplace_update(mu, cov, psi_mu, psi_var, x, sigma2, curvature: str = "moment"):
    """Posterior (μ, Σ) of β after one sample x (Laplace about the prior mean).

    Args:
        mu: (n,) prior mean. cov: (n, n) prior covariance.
        psi_mu: (n,) feature mean. psi_var: (n,) feature variances (diagonal Σ_ψ).
        x: the measured position. sigma2: σ_ε².
        curvature: ``moment`` (default): the likelihood's variance s(β) is held at the
            expansion point β̄ = μ, so the step is the exact Gaussian update with the noise
            inflated by the feature uncertainty, β̄ᵀΣ_ψβ̄ + σ²; ``fisher``/``hessian``: the full
            one-step Laplace of the paper with the variance gradient (see module docstring —
            it overshoots when r² ≫ s, which the tests demonstrate).
    """
    Sb = psi_var * mu
    s = float(mu @ Sb) + sigma2
    r = x - float(mu @ psi_mu)
    if curvature == "moment":
        Cp = cov @ psi_mu
        k = Cp / (s + float(psi_mu @ Cp))
        new_cov = cov - np.outer(k, Cp)
        return mu + k * r, 0.5 * (new_cov + new_cov.T)
    g = r * psi_mu / s + (r * r / s ** 2 - 1.0 / s) * Sb
    if curvature == "hessian":
        _, H = grad_hess(mu, psi_mu, psi_var, x, sigma2)
        prec = np.linalg.inv(cov) - H
        try:
            c = np.linalg.cholesky(prec)
        except np.linalg.LinAlgError:
            c = None
        if c is not None:
            new_cov = np.linalg.inv(prec)
            new_cov = 0.5 * (new_cov + new_cov.T)
            return mu + new_cov @ g, new_cov
    # Fisher: precision + U Uᵀ with U = [μ_ψ/√s, √2 Σ_ψβ/s]  (Woodbury, rank 2)
    U = np.column_stack([psi_mu / np.sqrt(s), np.sqrt(2.0) * Sb / s])
    CU = cov @ U
    M = np.eye(2) + U.T @ CU
    new_cov = cov - CU @ np.linalg.solve(M, CU.T)
    new_cov = 0.5 * (new_cov + new_cov.T)
    return mu + new_cov @ g, new_cov


def conjugate_update(mu, cov, psi, x, sigma2):
    """Eq. 19: exact posterior for deterministic features; ``psi`` (m, n), ``x`` (m,) — one
    sample or a batch."""
    psi = np.atleast_2d(psi)
    x = np.atleast_1d(x)
    CP = cov @ psi.T
    M = sigma2 * np.eye(psi.shape[0]) + psi @ CP
    K = np.linalg.solve(M, CP.T).T
    new_mu = mu + K @ (x - psi @ mu)
    new_cov = cov - K @ CP.T
    return new_mu, 0.5 * (new_cov + new_cov.T)


def predict(mu, cov, psi_mu, psi_var, sigma2):
    """Posterior predictive mean and variance of x = βᵀψ + ε (β, ψ independent Gaussians).

    var = μ_βᵀΣ_ψμ_β + μ_ψᵀΣ_βμ_ψ + tr(Σ_βΣ_ψ) + σ². The paper's Eq. 20 keeps only the second
    and last terms; the first (the known uncertainty of the features, i.e. of the FRFs) is the
    point of the uncertainty-aware twin, and the third is its interaction with the weights.
    Works on one sample (n,) or a batch (m, n)."""
    psi_mu = np.asarray(psi_mu)
    psi_var = np.asarray(psi_var)
    mean = psi_mu @ mu
    if psi_mu.ndim == 1:
        var = (mu * psi_var) @ mu + psi_mu @ cov @ psi_mu + float(np.diag(cov) @ psi_var) + sigma2
    else:
        var = (psi_var * mu * mu).sum(1) + np.einsum("ij,jk,ik->i", psi_mu, cov, psi_mu) \
            + psi_var @ np.diag(cov) + sigma2
    return mean, var


def rls_init(psi, x, lam):
    """Eq. 3: ridge initialisation β = (λI + ψψᵀ)⁻¹ψx, P = (λI + ψψᵀ)⁻¹."""
    P = np.linalg.inv(lam * np.eye(psi.size) + np.outer(psi, psi))
    return P @ psi * x, P


def rls_update(beta, P, psi, x, f0):
    """Eq. 4: recursive least squares with forgetting factor f0 (0 < f0 ≤ 1)."""
    Pp = P @ psi
    k = Pp / (f0 + psi @ Pp)
    beta = beta + k * (x - beta @ psi)
    P = (P - np.outer(k, Pp)) / f0
    return beta, 0.5 * (P + P.T)


@dataclass
class BayesianRegressor:
    """Thin stateful wrapper of :func:`laplace_update` / :func:`predict` (one axis)."""

    mu: np.ndarray
    cov: np.ndarray
    sigma2: float
    curvature: str = "moment"
    n_updates: int = 0

    def predict(self, psi_mu, psi_var):
        return predict(self.mu, self.cov, psi_mu, psi_var, self.sigma2)

    def update(self, psi_mu, psi_var, x):
        self.mu, self.cov = laplace_update(self.mu, self.cov, psi_mu, psi_var, x, self.sigma2,
                                           self.curvature)
        self.n_updates += 1
        return self
