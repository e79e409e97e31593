"""The digital twin of one axis and of the XY contour, run over a whole trajectory.

Coordinates are deviations from the first commanded sample (x_ref), so the regression weights
act on motion, not on where the part sits on the bed: a weight error δ on x̂ costs δ times the
distance travelled since the start, not δ times 117 mm.

Online use (paper Sec. 3, "one sample behind"): at sample t the features use the errors
e = x − x̂ measured up to t−1; the twin predicts x̃(t), then learns from the measured x(t).
Without measurements, the unknown errors are the twin's own predictions x̃ − x̂ (paper Eq. 5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg.blas import dger

from .features import factor_series, feature_matrix, n_features, physics_prior, xhat
from .frf import ImpulseResponse, impulse_response


@dataclass
class AxisTwin:
    """Twin of one axis: Gaussian impulse response + Bayesian weights.

    Attributes:
        ir: the known-uncertainty impulse response.
        n2, n3: feature orders. sigma2: σ_ε², mm².
        mu, cov: current weight mean (d,) and covariance (d, d).
        use_feature_var: False gives the deterministic-feature twin (the paper's DD method).
    """

    ir: ImpulseResponse
    n2: int
    n3: int
    sigma2: float
    mu: np.ndarray
    cov: np.ndarray
    use_feature_var: bool = True
    curvature: str = "moment"

    def run(self, x_cmd: np.ndarray, x_meas: np.ndarray | None = None, *, learn: bool = True):
        """Predict (and learn) over a trajectory.

        Args:
            x_cmd: (T,) commanded position, mm.
            x_meas: (T,) measured position, mm, or None.
            learn: update the weights from x_meas, one sample behind.

        Returns:
            mean (T,), std (T,) of the predicted actual position, mm; the weights are left
            in ``mu``/``cov`` (the twin keeps learning across calls).

        The feature covariance is the *full* one: the x̂ lags are correlated with each other,
        and e = x − x̂ is perfectly anti-correlated with x̂ (x is measured). The paper's Eq. 13
        treats the features as uncorrelated; once the twin learns to feed back the last error,
        x̂(t) + e(t−1) ≈ x(t−1) + (x̂(t) − x̂(t−1)) is nearly certain, and the diagonal form
        would overstate its variance about tenfold (99.9 % coverage of a 95 % interval in
        tests/twin/test_calibration.py). We use βᵀΣ_ψβ = ||Σ_lag c_lag Y_{t−lag}||² with the
        signed weights of each lag (see features.factor_series); the small tr(Σ_βΣ_ψ) term
        keeps the diagonal approximation.
        """
        x_cmd = np.asarray(x_cmd, float)
        ref = float(x_cmd[0])
        w = x_cmd - ref
        xm, xv = xhat(self.ir, x_cmd)
        xm = xm - ref
        Y = factor_series(self.ir, w) if self.use_feature_var else np.zeros((0, w.size))
        if not self.use_feature_var:
            xv = np.zeros_like(xv)
        T = x_cmd.size
        n2, n3 = self.n2, self.n3
        maxlag = max(n2, n3)
        # pad Y with zeros before the start so lags index cleanly
        Yp = np.hstack([np.zeros((Y.shape[0], maxlag)), Y])
        lag_x = np.arange(n2, -1, -1)  # columns 1..n2+1: x̂(t-n2) .. x̂(t)
        lag_e = np.arange(n3, 0, -1)  # e(t-n3) .. e(t-1)
        mean = np.empty(T)
        var = np.empty(T)
        mu, cov, s2 = self.mu, self.cov, self.sigma2
        measured = x_meas is not None
        e = (np.asarray(x_meas, float) - ref) - xm if measured else np.zeros(T)
        M, V = feature_matrix(xm, xv, e, n2, n3)
        first_e = 2 + n2
        if measured and learn and Y.shape[0] > 0:
            return self._run_joint(M, Y, x_meas - ref, lag_x, lag_e, maxlag, ref)
        for t in range(T):
            row = M[t]
            if not measured:
                row = row.copy()
                for j in range(n3):
                    k = t - (n3 - j)
                    row[first_e + j] = e[k] if k >= 0 else 0.0
            # signed weight of each lag: +β for x̂(t-lag), −β for e(t-lag)
            c = np.zeros(maxlag + 1)
            np.add.at(c, lag_x, mu[1:first_e])
            np.add.at(c, lag_e, -mu[first_e:])
            q = Yp[:, t + maxlag - np.arange(maxlag + 1)] @ c
            quad = float(q @ q)
            m_t = float(row @ mu)
            v_t = quad + float(row @ cov @ row) + float(np.diag(cov) @ V[t]) + s2
            mean[t] = m_t
            var[t] = v_t
            if measured and learn:
                # moment-form update with the full feature covariance in s
                Cp = cov @ row
                k = Cp / (quad + s2 + float(row @ Cp))
                mu = mu + k * (x_meas[t] - ref - m_t)
                cov = cov - np.outer(k, Cp)
            elif not measured:
                e[t] = m_t - xm[t]
        self.mu, self.cov = mu, 0.5 * (cov + cov.T)
        return mean + ref, np.sqrt(np.maximum(var, 0.0))

    def _run_joint(self, M, Y, x_dev, lag_x, lag_e, maxlag, ref):
        """Learning with the plant draw as a latent variable.

        The known uncertainty is one fixed machine of the population: x̂(t) = E x̂(t) + Y_tᵀ z
        with z ~ N(0, I_r) the same for the whole log. The paper keeps ψ random at every
        sample, so its predictive variance never drops below the population's spread even
        once the log has shown which machine this is (98–99 % coverage of a 95 % interval).
        Here z is learned jointly with β by an extended Kalman update of θ = [β; z] on the
        bilinear model x = βᵀ(ψ̄ + G z) + ε (G maps z to the feature perturbations: +Y for the
        x̂ lags, −Y for the error lags), linearised at the current means."""
        T, d = M.shape
        r = Y.shape[0]
        first_e = 2 + self.n2
        Yp = np.hstack([np.zeros((r, maxlag)), Y])
        lags = np.arange(maxlag + 1)
        theta = np.concatenate([self.mu, np.zeros(r)])
        C = np.zeros((d + r, d + r), order="F")
        C[:d, :d] = self.cov
        C[d:, d:] = np.eye(r)
        s2 = self.sigma2
        sign = np.zeros((d, maxlag + 1))  # feature j <- lag column with sign
        for j, lag in enumerate(lag_x):
            sign[1 + j, lag] = 1.0
        for j, lag in enumerate(lag_e):
            sign[first_e + j, lag] = -1.0
        mean = np.empty(T)
        var = np.empty(T)
        J = np.empty(d + r)
        for t in range(T):
            Ylag = Yp[:, t + maxlag - lags]  # (r, maxlag+1)
            mz = theta[d:]
            psi_c = M[t] + sign @ (Ylag.T @ mz)
            mb = theta[:d]
            q = Ylag @ (sign.T @ mb)
            J[:d] = psi_c
            J[d:] = q
            m_t = float(psi_c @ mb)
            CJ = C @ J
            v_t = float(J @ CJ) + s2
            mean[t] = m_t
            var[t] = v_t
            k = CJ / v_t
            theta = theta + k * (x_dev[t] - m_t)
            # rank-one downdate in place (BLAS dger): C -= k CJᵀ, no (d+r)² temporary
            C = dger(-1.0, k, CJ, a=C, overwrite_a=1)
        self.mu = theta[:d]
        self.cov = 0.5 * (C[:d, :d] + C[:d, :d].T)
        return mean + ref, np.sqrt(np.maximum(var, 0.0))


def _signed(mu, lag_x, lag_e, maxlag, first_e):
    c = np.zeros(maxlag + 1)
    np.add.at(c, lag_x, mu[1:first_e])
    np.add.at(c, lag_e, -mu[first_e:])
    return c


def axis_twin(profile, axis: str, *, method: str = "pidd") -> AxisTwin:
    """The twin of one axis of a profile.

    method: ``pidd`` (known uncertainty + learned prior), ``pb`` (known uncertainty, the physics
    prior, no learning intended), ``dd`` (no known uncertainty, zero prior mean, broad prior)."""
    tw = profile.twin
    frf = profile.axes[axis].frf
    ir = impulse_response(frf, profile.ts_s, tw.n_taps, method=tw.coef_variance)
    d = n_features(tw.n2, tw.n3)
    if method == "dd":
        return AxisTwin(ir=ir, n2=tw.n2, n3=tw.n3, sigma2=tw.sigma_eps_mm ** 2, mu=np.zeros(d),
                        cov=np.eye(d), use_feature_var=False)
    prior = tw.priors.get(axis)
    if prior is not None:
        mu, cov = prior.mu.copy(), prior.cov.copy()
    else:
        mu, cov = physics_prior(tw.n2, tw.n3)
    return AxisTwin(ir=ir, n2=tw.n2, n3=tw.n3, sigma2=tw.sigma_eps_mm ** 2, mu=mu, cov=cov)
