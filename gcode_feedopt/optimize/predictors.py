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

from ..twin.blr import laplace_update
from ..vm.plant import simulate_axes


def _fir_tail(h: np.ndarray, dev_hist: np.ndarray, dev_h: np.ndarray) -> np.ndarray:
    """(h * [dev_hist, dev_h]) at the horizon samples (n,), using only the last len(h)−1
    history samples."""
    nt = h.size
    n = dev_h.size
    past = dev_hist[-(nt - 1):] if nt > 1 else dev_hist[:0]
    seq = np.concatenate([past, dev_h])
    full = np.convolve(seq, h)[: seq.size]
    return full[past.size:past.size + n]


def _taps_like(G, n_taps: int) -> np.ndarray:
    """(n_taps, k) of filters G (m, k) cut or zero-padded to n_taps rows; (n_taps, 0) for None."""
    if G is None:
        return np.zeros((n_taps, 0))
    G = np.asarray(G, float).reshape(np.shape(G)[0], -1)[:n_taps]
    return np.vstack([G, np.zeros((n_taps - G.shape[0], G.shape[1]))])


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

    def predict(self, k0: int, cmd_h: np.ndarray, jac: bool = True):
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


class _Growing:
    """An append-only float array (amortised O(1) appends, views without copies)."""

    def __init__(self, cap: int = 4096):
        self.a = np.zeros(cap)
        self.n = 0

    def extend(self, v) -> None:
        v = np.asarray(v, float).ravel()
        need = self.n + v.size
        if need > self.a.size:
            grown = np.zeros(max(need, 2 * self.a.size))
            grown[:self.n] = self.a[:self.n]
            self.a = grown
        self.a[self.n:need] = v
        self.n = need

    def tail(self, k0: int, m: int) -> np.ndarray:
        """Samples k0−m … k0−1, zero-padded before the start."""
        lo = k0 - m
        if lo >= 0:
            return self.a[lo:k0]
        return np.concatenate([np.zeros(-lo), self.a[:max(k0, 0)]])

    def __getitem__(self, i):
        return self.a[:self.n][i]

    def __setitem__(self, i, v):
        self.a[i] = v

    def __len__(self):
        return self.n


class TwinPredictor:
    """The uncertainty-aware twin over a window horizon, both axes (paper Sec. 3.2).

    Per axis, on deviations w from the first commanded sample: x̂ = μ_h * w with variance
    ||Lᵀw_t||² from the *full* tap covariance Σ_h = L Lᵀ (twin.features.xhat; the paper's
    diagonal Eq. 12 overstates a settled position's uncertainty more than tenfold, because
    every FRF draw keeps the certain DC gain); ψ_t = [1, x̂(t−n2)…x̂(t), e(t−n3)…e(t−1)];
    predictive mean μ_βᵀψ_t and variance (μ_β∘v_ψ)·μ_β + ψᵀΣ_βψ + diag(Σ_β)·v_ψ + σ_ε²
    (blr.predict). Unknown errors e (future, or never measured offline) are the twin's own
    predictions (Eq. 5); the mean is then the solution of a lower-triangular linear system
    in the horizon, so mean and Jacobian are computed in closed form (no per-sample loop).
    ``observe`` feeds measured positions: e becomes measured and, with ``learn``, the
    weights are updated sample by sample (blr.laplace_update, Eq. 18; Eq. 19 when Σ_ψ = 0).
    """

    def __init__(self, irs, n2: int, n3: int, sigma2: float, mu, cov, *,
                 use_feature_var: bool = True, learn: bool = False, speed_var=0.0,
                 deviation_var=0.0, residual=None):
        self.h = [np.asarray(ir.mean, float) for ir in irs]
        #: per axis (x, y), (n_taps, k) filters of the command deviation whose outputs the
        #: twin missed on the machine's logs (twin.residual, closedloop.learn), variance
        #: Σ_j (G_j * w)²; held to the impulse response's length (learn fits them at it)
        self.G = [_taps_like(None if residual is None else residual[a], self.h[a].size)
                  for a in range(2)]
        self.ts_s = float(irs[0].ts_s)
        #: k_v² per axis (x, y), s²: what the twin cannot predict that grows with the axis's
        #: commanded speed v (an unmodelled lag), variance k_v²·v² (closedloop.learn)
        self.kv2 = np.broadcast_to(np.asarray(speed_var, float), (2,)).copy()
        #: ρ² per axis: what the twin cannot predict in proportion to the dynamic error d it
        #: predicts (predicted − commanded position), variance ρ²·d² (closedloop.learn)
        self.rho2 = np.broadcast_to(np.asarray(deviation_var, float), (2,)).copy()
        self.L = [np.asarray(ir.factor, float) if use_feature_var else np.zeros((ir.mean.size, 0))
                  for ir in irs]
        self.n2, self.n3 = int(n2), int(n3)
        #: σ² per axis (x, y): a number is both axes'
        self.s2 = np.broadcast_to(np.asarray(sigma2, float), (2,)).copy()
        self.mu = [np.array(m, float) for m in mu]
        self.cov = [np.array(c, float) for c in cov]
        self.use_var = use_feature_var
        self.learn = learn
        self.ref = None
        self.w = [_Growing(), _Growing()]    # command deviation from ref
        self.xh = [_Growing(), _Growing()]   # x̂ mean (deviation)
        self.xv = [_Growing(), _Growing()]   # x̂ variance
        self.e = [_Growing(), _Growing()]    # measured or predicted e = x − x̂ (deviation)
        self.pred_mean = [[], []]  # the twin's prediction of each committed sample (absolute)
        self.pred_std = [[], []]
        self._free: dict = {}
        self._last = None
        self._toep: dict = {}
        self._rec: dict = {}
        self.maxlag = max(self.n2, self.n3)
        self.yhist = [None, None]  # last maxlag rows of the factor series per axis

    @property
    def d(self) -> int:
        return 1 + self.n2 + 1 + self.n3

    # -- physics part: x̂ over the horizon -------------------------------------------------
    def _history_matrix(self, a: int, k0: int, n: int) -> np.ndarray:
        """W (n, n_taps): W[t, q] = w(k0 + t − q) for k0 + t − q < k0 (history), else 0."""
        nt = self.h[a].size
        hist = self.w[a].tail(k0, nt)  # samples k0−nt … k0−1
        # W[t, q] = hist[nt + t − q] when q > t
        ext = np.concatenate([hist, np.zeros(n)])
        q = np.arange(nt)[None, :]
        t = np.arange(n)[:, None]
        idx = nt + t - q
        W = np.where(q > t, ext[np.clip(idx, 0, ext.size - 1)], 0.0)
        return W

    def _free_response(self, a: int, k0: int, n: int):
        key = (a, k0, n)
        got = self._free.get(key)
        if got is None:
            if len(self._free) > 8:
                self._free.clear()
            W = self._history_matrix(a, k0, n)
            got = (W @ self.h[a], W @ self.L[a], W @ self.G[a])
            self._free[key] = got
        return got

    def _toeplitz(self, a: int, n: int):
        key = (a, n)
        got = self._toep.get(key)
        if got is None:
            Jx = _jac(self.h[a], n)
            L = self.L[a]
            r = L.shape[1]
            TL = np.zeros((r, n, n))
            m = min(n, L.shape[0])
            for lag in range(m):
                idx = np.arange(lag, n)
                TL[:, idx, idx - lag] = L[lag][:, None]
            got = (Jx, TL)
            self._toep[key] = got
        return got

    def _xhat_h(self, a: int, k0: int, dev_h: np.ndarray):
        n = dev_h.size
        free_m, free_Y, _ = self._free_response(a, k0, n)
        Jx, TL = self._toeplitz(a, n)
        xm = free_m + Jx @ dev_h
        if TL.shape[0]:
            Y = free_Y + (TL @ dev_h).T
            xv = np.einsum("ij,ij->i", Y, Y)
        else:
            Y = np.zeros((n, 0))
            xv = np.zeros(n)
        return xm, xv, Jx, Y

    # -- regression part --------------------------------------------------------------------
    def _recursion(self, a: int, n: int):
        """Matrices of the horizon mean for the current weights: Sx (n, n) picks μ_x over the
        horizon x̂, Ae (n, n) μ_e over horizon errors, and (I − Ae)⁻¹."""
        key = (a, n)
        got = self._rec.get(key)
        if got is None:
            mu = self.mu[a]
            n2, n3 = self.n2, self.n3
            wx, we = mu[1:2 + n2], mu[2 + n2:]
            Sx = np.zeros((n, n))
            for j in range(n2 + 1):       # weight wx[j] on x̂(t − (n2 − j))
                lag = n2 - j
                idx = np.arange(lag, n)
                Sx[idx, idx - lag] += wx[j]
            Ae = np.zeros((n, n))
            for j in range(n3):           # weight we[j] on e(t − (n3 − j))
                lag = n3 - j
                idx = np.arange(lag, n)
                Ae[idx, idx - lag] += we[j]
            inv = np.linalg.inv(np.eye(n) - Ae)
            got = (Sx, Ae, inv)
            self._rec[key] = got
        return got

    def _axis(self, a: int, k0: int, dev_h: np.ndarray, jac: bool = True):
        n = dev_h.size
        n2, n3 = self.n2, self.n3
        mu, cov = self.mu[a], self.cov[a]
        xm, xv, Jx, Y = self._xhat_h(a, k0, dev_h)
        px = self.xh[a].tail(k0, n2)
        pv = self.xv[a].tail(k0, n2)
        pe = self.e[a].tail(k0, n3)
        pev = self.xv[a].tail(k0, n3)
        wx, we = mu[1:2 + n2], mu[2 + n2:]
        Sx, Ae, inv = self._recursion(a, n)
        # contributions of the history lags to each horizon sample
        allx_hist = np.concatenate([px, np.zeros(n)])
        alle_hist = np.concatenate([pe, np.zeros(n)])
        cx_hist = np.lib.stride_tricks.sliding_window_view(allx_hist, n2 + 1)[:n] @ wx
        ce_hist = np.lib.stride_tricks.sliding_window_view(alle_hist, n3)[:n] @ we \
            if n3 else np.zeros(n)
        rhs = mu[0] + cx_hist + ce_hist + Sx @ xm - Ae @ xm
        m = inv @ rhs
        Jm = inv @ ((Sx - Ae) @ Jx) if jac else None
        e_h = m - xm
        # feature means and variances over the horizon (cached lag index arrays)
        ix, ie = self._lag_index(n)
        allx = np.concatenate([px, xm])
        alle = np.concatenate([pe, e_h])
        P = np.empty((n, self.d))
        P[:, 0] = 1.0
        P[:, 1:2 + n2] = allx[ix]
        if n3:
            P[:, 2 + n2:] = alle[ie]
        var = self.s2[a] + np.einsum("ij,ij->i", P @ cov, P)
        if self.kv2[a]:
            v = np.diff(np.concatenate([self.w[a].tail(k0, 1), dev_h])) / self.ts_s
            var = var + self.kv2[a] * v * v
        if self.rho2[a]:
            var = var + self.rho2[a] * (m - dev_h) ** 2
        if self.G[a].shape[1]:
            R = self._residual_h(a, k0, dev_h)
            var = var + np.einsum("ij,ij->i", R, R)
        if self.use_var and Y.shape[1]:
            # β̄ᵀΣ_ψβ̄ with the full feature covariance (as twin.model.AxisTwin.run): the
            # random part of Σ_lag c_lag x̂(t − lag), c = +β_x on x̂ lags, −β_e on e lags
            # (e = x − x̂ inherits x̂'s uncertainty with the opposite sign)
            Yall = np.vstack([self._ytail(a, k0), Y])
            q = self._lag_matrix(a, n) @ Yall
            quad = np.einsum("ij,ij->i", q, q)
            dg = np.diag(cov)
            vx = np.concatenate([pv, xv])[ix] @ dg[1:2 + n2]
            ve = np.concatenate([pev, xv])[ie] @ dg[2 + n2:] if n3 else 0.0
            var = var + quad + vx + ve
        return m, Jm, np.sqrt(np.maximum(var, 0.0)), xm, xv, Y

    def _residual_h(self, a: int, k0: int, dev_h: np.ndarray) -> np.ndarray:
        """(n, k): the residual filters run over the history and the horizon deviations."""
        n = dev_h.size
        free_G = self._free_response(a, k0, n)[2]
        key = ("resid", a, n)
        TG = self._toep.get(key)
        if TG is None:
            TG = np.stack([_jac(g, n) for g in self.G[a].T])
            self._toep[key] = TG
        return free_G + (TG @ dev_h).T

    def _lag_index(self, n: int):
        """Index arrays (n, n2+1) and (n, n3) into [history, horizon] of the x̂ and e lags."""
        key = ("idx", n)
        got = self._rec.get(key)
        if got is None:
            t = np.arange(n)[:, None]
            got = (t + np.arange(self.n2 + 1)[None, :], t + np.arange(self.n3)[None, :])
            self._rec[key] = got
        return got

    def _lag_matrix(self, a: int, n: int) -> np.ndarray:
        """(n, maxlag + n) C with (C @ Yall)_t = Σ_lag c_lag Y_{t−lag} for the signed lag
        weights c of the current weights (rebuilt when the weights learn)."""
        key = ("lag", a, n)
        got = self._rec.get(key)
        if got is None:
            mu = self.mu[a]
            n2, n3, ml = self.n2, self.n3, self.maxlag
            c = np.zeros(ml + 1)
            np.add.at(c, np.arange(n2, -1, -1), mu[1:2 + n2])
            np.add.at(c, np.arange(n3, 0, -1), -mu[2 + n2:])
            got = np.zeros((n, ml + n))
            for lag in range(ml + 1):
                idx = np.arange(n)
                got[idx, idx + ml - lag] = c[lag]
            self._rec[key] = got
        return got

    def _ytail(self, a: int, k0: int) -> np.ndarray:
        """(maxlag, r) factor series of the samples k0−maxlag … k0−1 (zeros before start)."""
        ml, r = self.maxlag, self.L[a].shape[1]
        got = self.yhist[a]
        out = np.zeros((ml, r))
        if got is not None and got.shape[0]:
            take = got[-ml:]
            out[ml - take.shape[0]:] = take
        return out

    def predict(self, k0: int, cmd_h: np.ndarray, jac: bool = True):
        """Mean (2, n), Jacobian (2, n, n) (None with ``jac=False``) and std (2, n) of the
        predicted actual XY for horizon commands cmd_h after the committed history."""
        cmd_h = np.asarray(cmd_h, float)
        n = cmd_h.shape[0]
        if self.ref is None:
            self.ref = cmd_h[0].copy()
        mean = np.empty((2, n))
        std = np.empty((2, n))
        J = np.empty((2, n, n)) if jac else None
        parts = []
        for a in range(2):
            m, Jm, sd, xm, xv, Y = self._axis(a, k0, cmd_h[:, a] - self.ref[a], jac=jac)
            mean[a] = m + self.ref[a]
            std[a] = sd
            if jac:
                J[a] = Jm
            parts.append((m, sd, xm, xv, Y))
        # causal: a later commit of a prefix of cmd_h at k0 reuses these (commit below)
        self._last = (k0, cmd_h.copy(), parts)
        return mean, J, std

    #: commits longer than this are taken in chunks (the horizon Toeplitz stacks are
    #: (r, n, n); a long rest-to-rest move would otherwise build a huge one)
    COMMIT_CHUNK = 64

    def commit(self, k0: int, cmd: np.ndarray) -> None:
        cmd = np.asarray(cmd, float)
        if self.ref is None:
            self.ref = cmd[0].copy()
        last, self._last = self._last, None
        m_len = cmd.shape[0]
        reuse = (last is not None and last[0] == k0 and last[1].shape[0] >= m_len
                 and np.array_equal(last[1][:m_len], cmd))
        if not reuse and m_len > self.COMMIT_CHUNK:
            for j in range(0, m_len, self.COMMIT_CHUNK):
                self.commit(k0 + j, cmd[j:j + self.COMMIT_CHUNK])
            return
        for a in range(2):
            dev = cmd[:, a] - self.ref[a]
            if reuse:
                m, sd, xm, xv, Y = (v[:m_len] for v in last[2][a])
            else:
                m, _, sd, xm, xv, Y = self._axis(a, k0, dev, jac=False)
            prev = self.yhist[a]
            Y = Y if prev is None else np.vstack([prev, Y])
            self.yhist[a] = Y[-self.maxlag:]
            self.w[a].extend(dev)
            self.xh[a].extend(xm)
            self.xv[a].extend(xv)
            self.e[a].extend(m - xm)
            self.pred_mean[a].extend(m + self.ref[a])
            self.pred_std[a].extend(sd)
        self._free.clear()

    def load_history(self, ref, series, mean, std) -> None:
        """Start from a committed history instead of an empty one: ``series`` per axis
        (w, x̂, var x̂, e, Y) of H samples from ``predict_trajectory(series=True)`` (only the
        last n_taps matter: the twin is time-invariant, so a history cut to its memory
        predicts the same), ``mean``/``std`` (2, H) the predictions of those samples."""
        self.ref = np.asarray(ref, float).copy()
        for a in range(2):
            w, xm, xv, e, Y = series[a]
            for g, v in ((self.w[a], w), (self.xh[a], xm), (self.xv[a], xv), (self.e[a], e)):
                g.n = 0
                g.extend(v)
            self.yhist[a] = np.asarray(Y, float)[-self.maxlag:]
            self.pred_mean[a] = list(mean[a])
            self.pred_std[a] = list(std[a])
        self._free.clear()
        self._last = None

    def observe(self, k0: int, meas: np.ndarray) -> None:
        """Measured XY (m, 2) of committed samples k0…k0+m−1: errors become measured and,
        with ``learn``, the weights learn from each sample (one sample behind, as online)."""
        self._last = None
        meas = np.asarray(meas, float)
        n2, n3 = self.n2, self.n3
        for a in range(2):
            xh, xv, e = self.xh[a], self.xv[a], self.e[a]
            for j in range(meas.shape[0]):
                t = k0 + j
                x_dev = meas[j, a] - self.ref[a]
                if self.learn:
                    psi = np.concatenate([[1.0], xh.tail(t + 1, n2 + 1), e.tail(t, n3)])
                    if self.use_var:
                        var = np.concatenate([[0.0], xv.tail(t + 1, n2 + 1), xv.tail(t, n3)])
                    else:
                        var = np.zeros(psi.size)
                    self.mu[a], self.cov[a] = laplace_update(self.mu[a], self.cov[a], psi, var,
                                                             x_dev, self.s2[a])
                e[t] = x_dev - xh[t]
        if self.learn:
            self._rec.clear()


class PlantPredictor:
    """The oracle: the virtual machine's own plant (impulse responses and effects) run on
    the committed history plus the horizon; Jacobian from its impulse responses; zero std.
    Sensor noise is not part of the prediction (it is not motion)."""

    def __init__(self, plant):
        self.plant = plant
        self.effects = tuple(e for e in plant.effects if e.stage != "sensor")
        self.h = (plant.impulse["x"], plant.impulse["y"])
        self.cmd: list[np.ndarray] = []
        self._jac_cache = {}

    def commit(self, k0: int, cmd: np.ndarray) -> None:
        self.cmd.extend(np.asarray(cmd, float))

    def predict(self, k0: int, cmd_h: np.ndarray, jac: bool = True):
        cmd_h = np.asarray(cmd_h, float)
        n = cmd_h.shape[0]
        full = np.vstack([np.asarray(self.cmd, float).reshape(-1, 2), cmd_h])
        cmd3 = np.column_stack([full, np.zeros(full.shape[0])])
        out = simulate_axes(cmd3, self.plant.ts_s, self.plant.impulse, self.effects,
                            mode_hz=self.plant.mode_hz).actual_mm
        mean = out[-n:, :2].T
        jac = np.empty((2, n, n))
        for a in range(2):
            key = (a, n)
            if key not in self._jac_cache:
                self._jac_cache[key] = _jac(self.h[a], n)
            jac[a] = self._jac_cache[key]
        return mean, jac, np.zeros((2, n))


def _causal(x: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """Σ_lag taps[lag] x[t − lag] (zeros before the start), (K,)."""
    return _causal_many(x, np.asarray(taps, float)[:, None])[0]


#: overlap-add block of :func:`_causal_many`, samples (FFT of block + taps − 1), and blocks
#: transformed at once (temporaries of a few MB stay in cache)
OLA_BLOCK = 1 << 13
OLA_CHUNK = 8
#: filters this short (or with this few non-zero taps) are applied as shifted sums
SHORT_TAPS = 64


def _causal_many(x: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """Causal convolutions of one signal with several filters at once, (m, K):
    out[j, t] = Σ_lag taps[lag, j] x[t − lag] (zeros before the start).

    Overlap-add with one real FFT of each block of x shared by all m filters (the twin
    filters one command by its mean impulse response and by every direction of its
    covariance factor); short or sparse filters are shifted sums over their non-zero taps."""
    import scipy.fft as sfft

    x = np.asarray(x, float)
    taps = np.asarray(taps, float)
    K = x.size
    n, m = taps.shape
    if n == 0 or m == 0 or K == 0:
        return np.zeros((m, K))
    nz = np.flatnonzero(np.any(taps != 0.0, axis=1))
    if nz.size == 0:
        return np.zeros((m, K))
    if nz.size <= 8 or n <= SHORT_TAPS or K <= n:
        return _causal_short(np.broadcast_to(x, (m, K)), taps.T)
    B = min(OLA_BLOCK, max(K, 256))
    nfft = sfft.next_fast_len(B + n - 1, real=True)
    H = sfft.rfft(taps.T, nfft, axis=1)                      # (m, nf)
    nb = -(-K // B)
    xp = np.zeros(nb * B)
    xp[:K] = x
    xb = xp.reshape(nb, B)
    out = np.zeros((m, nb * B + nfft))
    for c0 in range(0, nb, OLA_CHUNK):
        c1 = min(nb, c0 + OLA_CHUNK)
        X = sfft.rfft(xb[c0:c1], nfft, axis=1)               # (c, nf)
        Y = sfft.irfft(X[:, None, :] * H[None, :, :], nfft, axis=-1)  # (c, m, nfft)
        for i in range(c1 - c0):
            lo = (c0 + i) * B
            out[:, lo:lo + nfft] += Y[i]
    return out[:, :K]


def _causal_short(X: np.ndarray, taps: np.ndarray) -> np.ndarray:
    """Row-wise Σ_lag taps[.., lag] X[.., t − lag] for short filters: X (m, K); taps (L,)
    shared by every row, or (m, L) one per row. Returns (m, K)."""
    X = np.asarray(X, float)
    taps = np.asarray(taps, float)
    K = X.shape[-1]
    per_row = taps.ndim == 2
    lags = np.flatnonzero(np.any(taps != 0.0, axis=0) if per_row else taps != 0.0)
    if lags.size == 1 and lags[0] == 0:
        # one tap at lag 0 (the physics prior's weight 1 on the current x̂): a scaling
        return X * (taps[:, :1] if per_row else taps[0])
    out = np.zeros(X.shape)
    for lag in lags:
        if lag < K:
            w = taps[:, lag][:, None] if per_row else taps[lag]
            out[..., lag:] += w * X[..., :K - lag]
    return out


#: rows of the feature matrix formed at once by ``predict_trajectory`` (memory: rows × d).
TRAJ_CHUNK = 1 << 16


def predict_trajectory(tp: TwinPredictor, cmd: np.ndarray, series: bool = False,
                       ref: np.ndarray | None = None):
    """The offline twin over a whole commanded XY trajectory, vectorized.

    Equal to committing ``cmd`` to a fresh ``TwinPredictor`` (no measurements, no learning)
    and reading ``pred_mean``/``pred_std`` (test: 1e-9), but without the per-window loop: x̂
    and the factor series are FFT convolutions, the self-predicted errors (paper Eq. 5)
    follow the AR recursion e_t = μ₀ + Σ β_x x̂_{t−lag} − x̂_t + Σ β_e e_{t−lag} (one
    ``lfilter``), and the variance terms are lag convolutions plus ψᵀΣ_βψ in row chunks.
    A whole Benchy (1.2 M samples per axis) takes seconds. Long for a reason: one vectorized
    pass whose steps mirror TwinPredictor's recursion term by term (and are tested against it).

    ``ref``: (K, 2) per-sample reference the deviations are taken from (default: the first
    command, as the windowed twin). Several independent windows can be predicted in one call
    by concatenating them with each window's first command as its reference: the twin is
    time-invariant and its prior shift-invariant (twin.features.shift_invariant_cov), so a window
    predicts its own samples exactly once it holds the twin's memory (n_taps + max(n2, n3)
    samples) of history; before that the jump between windows is still in the filters.

    Returns mean (2, K) absolute mm and std (2, K) mm of the predicted actual position;
    with ``series`` also, per axis, the internal series (w, x̂, var x̂, e, Y) that
    ``TwinPredictor.load_history`` takes."""
    from scipy.signal import lfilter

    cmd = np.asarray(cmd, float)
    K = cmd.shape[0]
    ref = cmd[0] if ref is None else np.asarray(ref, float)
    if ref.ndim == 2 and ref.shape != cmd.shape:
        raise ValueError(f"ref must be (2,) or {cmd.shape}, got {ref.shape}")
    n2, n3 = tp.n2, tp.n3
    d = tp.d
    mean = np.empty((2, K))
    std = np.empty((2, K))
    out = []
    for a in range(2):
        mu, cov = tp.mu[a], tp.cov[a]
        ref_a = ref[..., a]
        w = cmd[:, a] - ref_a
        L = tp.L[a]
        r = L.shape[1]
        # x̂ and the factor series Y (x̂'s uncertainty) in one batched convolution
        G = tp.G[a]
        conv = _causal_many(w, np.column_stack([tp.h[a], L, G]))
        xm = conv[0]
        Y = conv[1:1 + r]                 # (r, K)
        R = conv[1 + r:]                  # (k, K): the residual filters' outputs
        xv = np.einsum("ij,ij->j", Y, Y) if r else np.zeros(K)
        wx, we = mu[1:2 + n2], mu[2 + n2:]
        cx = np.zeros(n2 + 1)            # cx[lag] = weight of x̂(t − lag)
        cx[np.arange(n2, -1, -1)] = wx
        drive = mu[0] + _causal_short(xm[None, :], cx)[0] - xm
        if n3 and np.any(we != 0.0):
            ce = np.zeros(n3 + 1)        # AR: e_t − Σ ce[lag] e_{t−lag} = drive
            ce[np.arange(n3, 0, -1)] = we
            e = lfilter([1.0], np.concatenate([[1.0], -ce[1:]]), drive)
        else:
            e = drive
        m = e + xm
        var = np.full(K, tp.s2[a])
        if tp.kv2[a]:
            # the commanded speed (0 at each window's first sample, whose past is elsewhere)
            v = np.zeros(K)
            v[1:] = np.diff(cmd[:, a]) / tp.ts_s
            if np.ndim(ref) == 2:
                v[1:][np.any(ref[1:] != ref[:-1], axis=1)] = 0.0
            var += tp.kv2[a] * v * v
        if tp.rho2[a]:
            var += tp.rho2[a] * (m - w) ** 2
        if R.shape[0]:
            var += np.einsum("ij,ij->j", R, R)
        # ψᵀΣ_βψ in chunks of rows, over the feature columns that are not identically zero
        # (offline with the physics prior every self-predicted error e is 0)
        use_e = bool(n3) and bool(np.any(e != 0.0))
        dd = d if use_e else 2 + n2
        cov_u = cov[:dd, :dd]
        xpad = np.concatenate([np.zeros(n2), xm])
        epad = np.concatenate([np.zeros(n3), e]) if use_e else None
        for lo in range(0, K, TRAJ_CHUNK):
            hi = min(K, lo + TRAJ_CHUNK)
            P = np.empty((hi - lo, dd))
            P[:, 0] = 1.0
            P[:, 1:2 + n2] = np.lib.stride_tricks.sliding_window_view(
                xpad[lo:hi + n2], n2 + 1)
            if use_e:
                P[:, 2 + n2:] = np.lib.stride_tricks.sliding_window_view(
                    epad[lo:hi + n3 - 1], n3)
            var[lo:hi] += np.einsum("ij,ij->i", P @ cov_u, P)
        if tp.use_var and r:
            ml = tp.maxlag
            c = np.zeros(ml + 1)
            np.add.at(c, np.arange(n2, -1, -1), wx)
            np.add.at(c, np.arange(n3, 0, -1), -we)
            q = _causal_short(Y, c) if np.count_nonzero(c) <= SHORT_TAPS else \
                lfilter(c, [1.0], Y, axis=1)
            quad = np.einsum("ij,ij->j", q, q)
            dg = np.diag(cov)
            vx = np.zeros(n2 + 1)
            vx[np.arange(n2, -1, -1)] = dg[1:2 + n2]
            taps = vx
            if n3:
                ve = np.zeros(n3 + 1)
                ve[np.arange(n3, 0, -1)] = dg[2 + n2:]
                taps = np.concatenate([vx, np.zeros(max(0, ve.size - vx.size))])
                taps[:ve.size] += ve
            var += quad + lfilter(taps, [1.0], xv)
        mean[a] = m + ref_a
        std[a] = np.sqrt(np.maximum(var, 0.0))
        if series:
            out.append((w, xm, xv, e, Y.T))
    if series:
        return mean, std, out
    return mean, std
