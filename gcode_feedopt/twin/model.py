"""The digital twin of one axis and of the XY contour, run over a whole trajectory.

Coordinates are deviations from the first commanded sample (x_ref), so the regression weights
act on motion, not on where the part sits on the bed: a weight error δ on x̂ costs δ times the
distance travelled since the start, not δ times 117 mm.

Online use (paper Sec. 3, "one sample behind"): at sample t the features use the errors
e = x − x̂ measured up to t−1; the twin predicts x̃(t), then learns from the measured x(t).
Without measurements, the unknown errors are the twin's own predictions x̃ − x̂ (paper Eq. 5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg.blas import dger

from .features import factor_series, feature_matrix, n_features, physics_prior, shift_invariant_cov, xhat
from .frf import ImpulseResponse
from .physics import axis_impulse
from .residual import filter_series


@dataclass
class AxisTwin:
    """Twin of one axis: Gaussian impulse response + Bayesian weights.

    Attributes:
        ir: the known-uncertainty impulse response.
        n2, n3: feature orders. sigma2: σ_ε², mm².
        mu, cov: current weight mean (d,) and covariance (d, d).
        use_feature_var: False gives the deterministic-feature twin (the paper's DD method).
        kv2, rho2: what ``learn`` found the twin cannot predict in proportion to the commanded
            speed (variance kv2·v², s²) and to the dynamic error it predicts (rho2·d², d the
            predicted minus the commanded position): added to an open-loop prediction's
            variance, as the optimizer's predictors add them (optimize.predictors).
        resid: (n_taps, k) filters of the command deviation w whose outputs ``learn`` found
            the twin to miss on the machine's logs (twin.residual): an open-loop prediction
            adds Σ_j (resid[:, j] * w)² to its variance, as the optimizer's predictors do.
    """

    ir: ImpulseResponse
    n2: int
    n3: int
    sigma2: float
    mu: np.ndarray
    cov: np.ndarray
    use_feature_var: bool = True
    curvature: str = "moment"
    kv2: float = 0.0
    rho2: float = 0.0
    resid: np.ndarray | None = None

    def run(self, x_cmd: np.ndarray, x_meas: np.ndarray | None = None, *, learn: bool = True,
            sigma_eps_mm: float | None = None, offset_mm: np.ndarray | None = None,
            extra_var_mm2: float = 0.0, warmup: int = 0):
        """``_run`` with a profile's extensions (``twin.extensions``): the known deterministic
        term ``offset_mm`` (T,) is taken off the measurements and added to the prediction, the
        variance ``extra_var_mm2`` (a fan of unknown phase) added to its variance."""
        if offset_mm is None and not extra_var_mm2:
            return self._run(x_cmd, x_meas, learn=learn, sigma_eps_mm=sigma_eps_mm, warmup=warmup)
        off = np.zeros(np.size(x_cmd)) if offset_mm is None else np.asarray(offset_mm, float)
        meas = None if x_meas is None else np.asarray(x_meas, float) - off
        mean, std = self._run(x_cmd, meas, learn=learn, sigma_eps_mm=sigma_eps_mm, warmup=warmup)
        return mean + off, np.sqrt(std * std + float(extra_var_mm2))

    def _run(self, x_cmd: np.ndarray, x_meas: np.ndarray | None = None, *, learn: bool = True,
             sigma_eps_mm: float | None = None, warmup: int = 0):
        """Predict (and learn) over a trajectory.

        Args:
            x_cmd: (T,) commanded position, mm.
            x_meas: (T,) measured position, mm, or None.
            learn: update the weights from x_meas, one sample behind.
            sigma_eps_mm: the noise σ_ε of the measurements. None: the profile's without
                measurements; with measurements, the sensor's noise estimated from them
                (``noise_floor_mm`` of measured − physics, never assumed), and while learning
                also the level of what the twin still cannot explain (see ``_run_joint``).
            warmup: samples at the start whose prediction depends on motion before x_cmd[0]
                (a log that starts mid-motion, ``closedloop.logs.twin_memory``): the history
                of the convolution is held at x_cmd[0]; these samples are predicted but
                neither learned from nor used for the noise estimate, so from ``warmup`` on the
                output does not depend on that unknown past (nor on x_meas before it, beyond
                the features' own lags).

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

        Long for a reason: the reference recursion, sample by sample as the paper states it
        (Eqs. 5, 12–14); the vectorized predictors (optimize.predictors) are tested against it.
        """
        x_cmd = np.asarray(x_cmd, float)
        ref = float(x_cmd[0])
        w = x_cmd - ref
        xm, xv = xhat(self.ir, x_cmd)
        Y = factor_series(self.ir, w) if self.use_feature_var else np.zeros((0, w.size))
        if sigma_eps_mm is not None:
            self.sigma2 = float(sigma_eps_mm) ** 2
        elif x_meas is not None:
            w0 = min(int(warmup), x_cmd.size - 8) if warmup > 0 else 0
            self.sigma2 = sensor_noise_mm(np.asarray(x_meas, float)[w0:] - xm[w0:], Y[:, w0:]) ** 2
        xm = xm - ref
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
        # Without learning the twin predicts open loop, from the commands alone (the errors it
        # feeds back are its own predictions, Eq. 5): the error-feedback weights are at their
        # prior mean 0, so measured errors would only add their prior variance — an interval
        # that depends on how wrong the physics happened to be (99 % coverage of a 95 %
        # interval on plants drawn from the profile's own spread). The measurements then only
        # give the noise level (above).
        measured = x_meas is not None and learn
        e = (np.asarray(x_meas, float) - ref) - xm if measured else np.zeros(T)
        M, V = feature_matrix(xm, xv, e, n2, n3)
        first_e = 2 + n2
        if measured and Y.shape[0] > 0:
            return self._run_joint(M, Y, x_meas - ref, lag_x, lag_e, maxlag, ref, warmup)
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
            if measured and t >= warmup:
                # moment-form update with the full feature covariance in s
                Cp = cov @ row
                k = Cp / (quad + s2 + float(row @ Cp))
                mu = mu + k * (x_meas[t] - ref - m_t)
                cov = cov - np.outer(k, Cp)
            elif not measured:
                e[t] = m_t - xm[t]
        self.mu, self.cov = mu, 0.5 * (cov + cov.T)
        if not measured and (self.kv2 or self.rho2):
            v = np.zeros(T)
            v[1:] = np.diff(w) / self.ir.ts_s
            var = var + self.kv2 * v * v + self.rho2 * (mean - w) ** 2
        if not measured and self.resid is not None and self.resid.size:
            R = filter_series(self.resid, w)
            var = var + np.einsum("ij,ij->j", R, R)
        return mean + ref, np.sqrt(np.maximum(var, 0.0))

    def _run_joint(self, M, Y, x_dev, lag_x, lag_e, maxlag, ref, warmup=0):
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
        # What the twin still cannot explain is estimated from the data, not assumed: the
        # noise variance is the larger of the sensor's (``s2``, from the log) and an
        # exponentially weighted mean of the innovations' excess over the twin's own
        # variance (covariance matching). With an unmodelled effect left, the innovations
        # stay large, the noise estimate follows them and the interval widens with it.
        lam = s2
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
            jcj = float(J @ CJ)
            v_t = jcj + max(s2, lam)
            mean[t] = m_t
            var[t] = v_t
            if t < warmup:  # the unknown past still shapes this sample: do not learn from it
                continue
            k = CJ / v_t
            innov = x_dev[t] - m_t
            lam += NOISE_FORGET * (innov * innov - jcj - lam)
            theta = theta + k * innov
            # rank-one downdate in place (BLAS dger): C -= k CJᵀ, no (d+r)² temporary
            C = dger(-1.0, k, CJ, a=C, overwrite_a=1)
        self.mu = theta[:d]
        self.cov = 0.5 * (C[:d, :d] + C[:d, :d].T)
        self.sigma2_learned = max(s2, lam)
        #: which machine of the population the log showed: z's posterior (r,), (r, r)
        self.z_mean = theta[d:].copy()
        self.z_cov = 0.5 * (C[d:, d:] + C[d:, d:].T)
        return mean + ref, np.sqrt(np.maximum(var, 0.0))


#: Weight of each new innovation in the running estimate of what the twin cannot explain
#: (≈ the last 1/0.02 = 50 samples, 0.1 s at 2 ms).
NOISE_FORGET = 0.02
#: The smallest noise the twin assumes, mm (a 0.1 µm encoder is finer than any printer's).
NOISE_FLOOR_MIN_MM = 1e-4


def noise_floor_mm(residual_mm: np.ndarray) -> float:
    """Robust RMS of the white part of a residual (measured − predicted), mm.

    The second difference of white noise of variance σ² has variance 6σ², while a smooth model
    error (what the twin misses is motion-shaped) contributes little to it at Ts: σ̂ =
    1.4826·MAD(Δ²r)/√6. This is the sensor's noise (encoder quantisation and electrical noise),
    which no model of the motion can predict and every interval must contain."""
    r = np.asarray(residual_mm, float)
    if r.size < 8:
        return 0.0
    d2 = np.diff(r, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def sensor_noise_mm(residual_mm: np.ndarray, Y: np.ndarray) -> float:
    """The sensor noise of a log: ``noise_floor_mm`` of the residual (measured − the physics'
    mean) once the part any machine of the profile's population could explain is taken out
    (the known-uncertainty directions Y (r, T), weights z ~ N(0, I) fitted by ridge least
    squares). Without that step the spread between the mean machine and this one leaks into
    the estimate where the motion is fast (0.76–0.91 µm instead of benchA's 0.62 µm)."""
    r = np.asarray(residual_mm, float)
    s0 = max(noise_floor_mm(r), NOISE_FLOOR_MIN_MM)
    if Y.shape[0]:
        G = Y @ Y.T + s0 * s0 * np.eye(Y.shape[0])
        z = np.linalg.solve(G, Y @ (r - r[0]))
        r = r - z @ Y
    return max(noise_floor_mm(r), NOISE_FLOOR_MIN_MM)


def _signed(mu, lag_x, lag_e, maxlag, first_e):
    c = np.zeros(maxlag + 1)
    np.add.at(c, lag_x, mu[1:first_e])
    np.add.at(c, lag_e, -mu[first_e:])
    return c


def axis_prior(profile, axis: str, *, method: str = "pidd") -> tuple[np.ndarray, np.ndarray]:
    """(μ_β (d,), Σ_β (d, d)) the twin of one axis starts from: the profile's learned prior or
    the physics prior, its x̂ block made shift-invariant (features.shift_invariant_cov: the
    features are deviations from the first sample, and independent x̂ weights would make the
    interval grow with the distance from it); ``dd``: zero mean, unit covariance."""
    tw = profile.twin
    d = n_features(tw.n2, tw.n3)
    if method == "dd":
        return np.zeros(d), np.eye(d)
    prior = tw.priors.get(axis)
    if prior is not None:
        mu, cov = np.array(prior.mu, float), np.array(prior.cov, float)
    else:
        mu, cov = physics_prior(tw.n2, tw.n3)
    return mu, shift_invariant_cov(cov, tw.n2)


def _last_recorded(prior, key: str, present=lambda v: v is not None):
    """The value ``key`` of the last record of ``Prior.learned_from`` whose value is
    ``present`` (the profile's YAML carries the records as they are), or None."""
    if prior is None:
        return None
    for rec in reversed(tuple(prior.learned_from)):
        got = rec.get(key) if isinstance(rec, dict) else None
        if present(got):
            return got
    return None


def _learned(prior, key: str):
    """:func:`_last_recorded` of a number, as float, or None."""
    got = _last_recorded(prior, key)
    return None if got is None else float(got)


def learned_noise_mm(prior) -> float | None:
    """The level of what the twin cannot predict that ``learn`` measured on this axis's logs
    (``closedloop.learn``: the RMS of the open-loop residual once the weights and the plant
    draw have explained what they can), mm; None when nothing was learned. It is kept in the
    last record of ``Prior.learned_from`` (``noise_level_mm``)."""
    return _learned(prior, "noise_level_mm")


def learned_speed_noise_s(prior) -> float:
    """k_v, s: the part of what the twin cannot predict that ``learn`` found to grow with the
    axis's commanded speed v (σ = k_v·|v|: an unmodelled lag, which ``diagnose`` can name);
    0 when nothing was learned."""
    return _learned(prior, "noise_per_speed_s") or 0.0


def learned_deviation_noise(prior) -> float:
    """ρ: the part of what the twin cannot predict that ``learn`` found in proportion to the
    dynamic error the twin predicts (σ = ρ·|predicted − commanded|: dynamics a few per cent
    wrong); 0 when nothing was learned."""
    return _learned(prior, "noise_per_deviation") or 0.0


def learned_filters(prior) -> list:
    """The residual filters (``[{"weight", "taps"}, ...]``, twin.residual) of the last record of
    ``Prior.learned_from`` that has any, as written; [] when none has."""
    return list(_last_recorded(prior, "residual_filters", present=bool) or [])


def learned_residual(prior) -> np.ndarray | None:
    """(n_taps, k): the filters of the command whose outputs ``learn`` found the twin to miss
    on this axis's logs (twin.residual), each scaled by the square root of its weight in the
    average over logs; None when nothing was learned (:func:`learned_filters`)."""
    cols = [math.sqrt(float(f["weight"])) * np.asarray(f["taps"], float)
            for f in learned_filters(prior)]
    cols = [c for c in cols if c.size and np.any(c != 0.0)]
    if not cols:
        return None
    n = max(c.size for c in cols)
    return np.column_stack([np.pad(c, (0, n - c.size)) for c in cols])


def axis_residual(profile, axis: str, *, method: str = "pidd") -> np.ndarray | None:
    """:func:`learned_residual` of one axis as the twin and the optimizer use it (None for
    ``dd``, which starts from nothing)."""
    return None if method == "dd" else learned_residual(profile.twin.priors.get(axis))


def learned_variance_terms(profile, axis: str, *, method: str = "pidd") -> tuple[float, float]:
    """(k_v², ρ²) of one axis as the optimizer and an open-loop prediction add them (variance
    k_v²·v² + ρ²·d², :func:`learned_speed_noise_s`, :func:`learned_deviation_noise`); zeros
    for ``dd``, which starts from nothing."""
    prior = None if method == "dd" else profile.twin.priors.get(axis)
    return learned_speed_noise_s(prior) ** 2, learned_deviation_noise(prior) ** 2


def axis_noise_mm(profile, axis: str, *, method: str = "pidd") -> float:
    """σ of what the twin of one axis cannot predict, mm, as the optimizer and an offline
    prediction use it: the level ``learn`` measured on the machine's own logs when there is
    one (a fan, a disturbance the profile lacks: the chance constraint keeps its margin), the
    profile's σ_ε otherwise (and always for ``dd``, which starts from nothing)."""
    level = None if method == "dd" else learned_noise_mm(profile.twin.priors.get(axis))
    return profile.twin.sigma_eps_mm if level is None else max(level, NOISE_FLOOR_MIN_MM)


def learned_draw(prior, r: int):
    """Which machine of the profile's population ``learn`` found the logs to come from: (z
    (r,), S (r, r)) with the plant draw z' = z + S u, u ~ N(0, I_r), in the directions of the
    axis's known uncertainty (h = E h + L z'); None when nothing was learned (or the physics
    changed its number of directions since). Kept in the last record of ``Prior.learned_from``
    that has one (``plant_draw``)."""
    got = _last_recorded(prior, "plant_draw")
    if got is None:
        return None
    z = np.asarray(got["z"], float)
    S = np.asarray(got["sqrt_cov"], float)
    if z.shape != (r,) or S.shape != (r, r):
        return None
    return z, S


def twin_impulse(profile, axis: str, *, method: str = "pidd") -> ImpulseResponse:
    """The Gaussian impulse response the twin of one axis uses: the profile's (the FRF
    population, ``twin.physics.axis_impulse``) or, once ``learn`` has seen logs of this
    machine, the population narrowed to it: mean E h + L z, factor L S (``learned_draw``).
    The virtual machine keeps drawing plants from the population itself."""
    ir = axis_impulse(profile, axis)
    got = None if method == "dd" else learned_draw(profile.twin.priors.get(axis),
                                                   ir.factor.shape[1])
    if got is None:
        return ir
    z, S = got
    L = ir.factor @ S
    return ImpulseResponse(ts_s=ir.ts_s, mean=ir.mean + ir.factor @ z,
                           var=np.einsum("ij,ij->i", L, L), factor=L)


def axis_twin(profile, axis: str, *, method: str = "pidd") -> AxisTwin:
    """The twin of one axis of a profile.

    method: ``pidd`` (known uncertainty + learned prior), ``pb`` (known uncertainty, the physics
    prior, no learning intended), ``dd`` (no known uncertainty, zero prior mean, broad prior)."""
    tw = profile.twin
    mu, cov = axis_prior(profile, axis, method=method)
    kv2, rho2 = learned_variance_terms(profile, axis, method=method)
    return AxisTwin(ir=twin_impulse(profile, axis, method=method), n2=tw.n2, n3=tw.n3,
                    sigma2=axis_noise_mm(profile, axis, method=method) ** 2, mu=mu, cov=cov,
                    use_feature_var=method != "dd", kv2=kv2, rho2=rho2,
                    resid=axis_residual(profile, axis, method=method))
