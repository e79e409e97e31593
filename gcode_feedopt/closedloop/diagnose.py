"""Diagnose what the twin gets wrong on a log, name the cause, measure the gain (issues 6, 19).

Pure numerics on arrays (``diagnose_arrays``); ``diagnose_log`` builds the physics from a
profile; the CLI ``gcode-feedopt diagnose`` reads the files.

**1. The twin's prediction and what the known uncertainty allows.** Per axis the twin's mean
impulse response h̄ (unit DC gain, ``twin.physics``) gives x̂ = x_0 + h̄ * (x_cmd − x_0). The
machine that made the log is one draw of the profile's population, h = h̄ + L z (L the factor of
the impulse-response covariance, z ~ N(0, I)): the columns of L convolved with the command are
the **baseline** regressors B, and z is fitted with ‖z‖ ≤ R, R² = χ²_r(0.999) (r = rank of L).
A mismatch that a machine inside the profile's spread could cause is absorbed by z; a bigger one
is not (a 10 % resonance shift is ~8 σ of a typical FRF set's spread and shows through). This is
what the twin does when it learns (``twin.model._run_joint``), with the draw bounded.

**2. The catalogue, shaped by the physics.** Each kind is a change of the model, fitted with the
baseline on the *fit part* of the log (the first ``fit_fraction``); its parameter is scanned,
then refined. A kind may have two forms, the one that fits better is taken (the form is reported):

- ``delay`` (``seconds``): the command reaches the motor late, x̂(t − d);
- ``gain`` (``scale``): the motor command scaled about the machine origin, x = s·x̂;
- ``resonance_shift`` (``frequency_hz``): the dominant mode moved as a mass change moves it
  (modal model, form ``mass``), the whole response rescaled in frequency (form ``scale``), or
  the load of the whole loop heavier by ``load_ratio`` behind a velocity feedback of corner
  ``corner_hz`` (form ``load``, ``ModalModel.loaded``: a servo's poles and damping move
  together; reported as the pole pair at the loaded response's peak);
- ``backlash`` (``magnitude_mm``, the total width of the play): the play acting on the command
  before the dynamics (form ``input``, a play between pulley and belt) or on the response (form
  ``output``), plus a free offset (where the band sits at the start is unknown); on an axis with
  integral action fitted with the twin's velocity lag error (``lag_s``, ``_lag_column``);
- ``friction`` (``magnitude_mm``, the quasi-static lag): a Coulomb force −F·sign(v) whose lag
  relaxes with a time constant τ once the axis stops (τ scanned, 0 = at once), through the
  axis dynamics (form ``response``), the force path (form ``force``) or as a following error
  at the output (form ``output``); on every axis also washed out by an integrator in
  ``integral_s`` (form ``integral``) or through the loop that holds the load, (1 − H)/(s (s +
  a)) with ``corner_hz`` a/2π (form ``loop``, ``ModalModel.load_force``); or
  a force of the carriage's own velocity, which sticks it at each reversal: a play of width
  2·magnitude on the response (form ``stick``, the same model as a backlash ``output``:
  where the held-out part cannot tell them apart, the backlash is named, the friction tied);
- ``periodic_time`` (``frequency_hz``, ``amplitude_mm``): a sinusoid in time (a fan), running
  throughout (form ``time``) or switched on during the log (form ``switched_on``,
  ``switched_on_s``: catalogue._switched_on);
- ``periodic_position`` (``wavelength_mm``, ``amplitude_mm``): a sinusoid of the commanded
  position (tooth pitch, screw runout, a stepper's electrical cycle: 0.3–60 mm) through the
  dynamics (``dynamics``) or at the output;
- ``cross_coupling`` (``from_axis`` and ``mm_per_mm_s2`` or ``coefficient``): the other axis's
  predicted acceleration through this axis's dynamics (form ``acceleration``, a frame force),
  its commanded acceleration through them (form ``command``, a motor force that follows the
  command), the predicted one through them twice (form ``belt``: a corexy's mismatched belts,
  ``twin.extensions``), the predicted or the commanded one through the response to a force
  on the frame (forms ``frame``, ``frame_command``) or, on a loop, on the load it holds
  (forms ``loop``, ``loop_command``, with ``corner_hz``), or its position (form
  ``position``, a skew).

**3. The test (stated).** Candidates are ranked by the sum of squares they explain on the fit
part. A candidate is named only if all hold:

- *fit part*: T_fit = ΔSS_fit / (SS_fit/N_eff) > χ²_q(1 − α/M), with q its free parameters,
  M the number of candidate parameter values tried in the round (Bonferroni over the scans)
  and N_eff the residual's effective sample count N / (1 + 2 Σ ρ_k) (the residual is
  coloured: its autocorrelation ρ_k is summed over the initial positive sequence);
- *held-out part* (never used to fit or scan): T_hold = ΔSS_hold / (SS_hold/N_eff) >
  χ²_1(1 − α): a held-out drop this large happens by chance with probability < α under "no
  effect", where over-fitting only raises held-out error;
- *relevance*: the effect explains ≥ ``MIN_EXPLAINED`` of the held-out residual SS (or, on
  an axis whose dominant mode rings, of what that mode's ring leaves, the effect beating the
  ring on both parts too: ``_ring_relevance``) and ≥ ``MIN_EFFECT_RMS_MM`` RMS (model error
  that small is below anything a tolerance sees).

α = ``ALPHA``. Up to ``MAX_EFFECTS`` effects are named greedily, each round on what the model
with the named ones leaves; a kind once per axis, but ``periodic_time`` and
``periodic_position`` (catalogue.REPEATABLE: two fans, a tooth pitch and a pulley's runout),
again only apart from those named (catalogue._apart). Among the passing candidates, those whose
fit-part SS is within crit_fit units of the leader's noise (SS_fit/N_eff) — the fit part cannot
tell them apart, as on steady motion where a delay, a friction and a backlash are one constant
lag — are told apart by the held-out part: the one explaining most of it is named. Friction and
backlash shift the steady motion alike (a play of width b lags like a friction lag b/2); where
the held-out part prefers the other one significantly (the same held-out statistic between the
two), the other is named; if the other one is not significantly worse on the held-out part, the
effect carries a stated ``tie`` with the other kind's parameter.

**4. Held-out RMS.** Per axis, of the twin's mean prediction (no plant draw) on the held-out
part: ``before`` with the profile as is, ``after`` with the named effects at their fitted
parameters, what ``extend_profile`` writes and the extended profile predicts (its deterministic
part; a periodic_time effect's phase is not kept: the extended profile carries it as variance).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats
from scipy.signal import oaconvolve

from ..errors import LogError
from ..twin.extensions import lag_regressor, mean_offsets
from ..twin.model import axis_twin, noise_floor_mm
from ..twin.physics import RINGING_ZETA, AxisPhysics, axis_physics, log_machine_command
from ..vm import effects as fx
from ..vm.plant import respond
from .catalogue import REPEATABLE, _candidates, _n_eff, _refine, _scan
from .extend import extend_profile

AXES = ("x", "y")
KINDS = ("periodic_time", "periodic_position", "backlash", "friction", "delay", "gain",
         "resonance_shift", "cross_coupling")
#: Significance level of both tests (module docstring, 3).
ALPHA = 0.01
#: Probability mass of the plant-draw ball ‖z‖ ≤ R the baseline may use.
DRAW_QUANTILE = 0.999
#: Fraction of the held-out residual SS a named effect must explain.
MIN_EXPLAINED = 0.2
#: Held-out RMS a named effect must explain, mm.
MIN_EFFECT_RMS_MM = 0.001
#: Effects named at most: a corexy's belt cross-talk takes two (one on each axis).
MAX_EFFECTS = 4
FIT_FRACTION = 0.6
#: A periodic_time within this fraction of a ringing mode's band must beat the mode's ring
#: (``_ring_bar``).
RING_BAND = 0.15


@dataclass
class Candidate:
    kind: str
    axis: str
    params: dict
    form: str
    ss_fit: float  # fit-part residual SS with this candidate, mm²
    ss_hold: float  # held-out residual SS with it, mm²
    explained_fit: float  # ΔSS on the fit part, mm²
    explained_hold: float  # ΔSS on the held-out part, mm²
    fraction: float  # ΔSS_hold / SS_hold before
    t_fit: float
    t_hold: float
    crit_fit: float
    crit_hold: float
    model: "_Model" = field(repr=False, default=None)
    #: the share of the held-out SS it explains beyond its axis's mode ring (``_ring_relevance``),
    #: where it passes both tests against that ring too; else None
    ring_fraction: float | None = None

    @property
    def passes(self) -> bool:
        relevant = self.fraction >= MIN_EXPLAINED or (self.ring_fraction is not None
                                                      and self.ring_fraction >= MIN_EXPLAINED)
        return (self.t_fit > self.crit_fit and self.t_hold > self.crit_hold and relevant
                and self.explained_hold > 0 and self.model is not None
                and math.sqrt(self.explained_hold / max(self.model.n_hold, 1)) >= MIN_EFFECT_RMS_MM)

    def to_dict(self) -> dict:
        return {"kind": self.kind, "axis": self.axis, "params": self.params, "form": self.form,
                "confidence": float(min(max(self.fraction, 0.0), 1.0)),
                "explained_fraction": float(self.fraction),
                "test": {"t_fit": float(self.t_fit), "crit_fit": float(self.crit_fit),
                         "t_holdout": float(self.t_hold), "crit_holdout": float(self.crit_hold),
                         **({"beyond_ring_fraction": float(self.ring_fraction)}
                            if self.ring_fraction is not None else {})}}


@dataclass
class Diagnosis:
    residual_rms_mm: dict
    effects: list
    holdout_rms_mm: dict
    candidates: list
    relations: dict
    spectrum: dict
    fit_samples: int
    warmup_samples: int = 0
    #: axis -> what the model with the named effects and the known uncertainty's bar leaves
    #: on the held-out part (``leftover``)
    leftover: dict = field(default_factory=dict)
    residual_mm: np.ndarray = field(repr=False, default=None)  # (K, 2) before
    corrected_mm: np.ndarray = field(repr=False, default=None)  # (K, 2) after (whole log)
    named: list = field(repr=False, default_factory=list)  # accepted Candidates

    def to_dict(self) -> dict:
        return {"residual_rms_mm": self.residual_rms_mm, "effects": self.effects,
                "holdout_rms_mm": self.holdout_rms_mm,
                "candidates": [c.to_dict() for c in self.candidates],
                "relations": self.relations, "spectrum": self.spectrum,
                "fit_samples": self.fit_samples, "warmup_samples": self.warmup_samples,
                "leftover": self.leftover,
                "test": {"alpha": ALPHA, "draw_quantile": DRAW_QUANTILE,
                         "min_explained": MIN_EXPLAINED, "min_effect_rms_mm": MIN_EFFECT_RMS_MM}}


# ---------------------------------------------------------------------------------------------
# physics (a profile's: twin.physics.axis_physics)


def _as_physics(impulse, ts_s) -> dict:
    out = {}
    for ax in AXES:
        p = impulse[ax]
        if isinstance(p, AxisPhysics):
            out[ax] = p
        else:
            mean, L = p
            L = np.zeros((mean.size, 0)) if L is None else np.asarray(L)
            out[ax] = AxisPhysics(np.asarray(mean, float), L, fx.dominant_mode_hz(mean, ts_s))
    return out


# ---------------------------------------------------------------------------------------------
# the model of one axis and its bounded fit


def _solve_bounded(A, b, nz, radius, lam0=0.0):
    """argmin θ of ‖y − Xθ‖² (given A = XᵀX, b = Xᵀy) with ‖θ[:nz]‖ ≤ radius: the trust-region
    subproblem, λ on the bounded block found by bisection in log λ.

    The bisection needs only ‖θ(λ)[:nz]‖: with the free block w eliminated (its Schur
    complement S on the bounded block, and the right side c), θ(λ)[:nz] = (S + λ I)⁻¹ c, so
    one eigendecomposition of S gives every step's norm (``_bounded_norm``); θ itself is
    solved once, at the λ found (the diagnosis fits ~10⁵ of these per log set)."""
    p = A.shape[0]
    D = np.zeros(p)
    D[:nz] = 1.0
    jitter = 1e-12 * (np.trace(A) / max(p, 1) + 1e-30)

    def sol(lam):
        M = A + np.diag(D * lam + jitter)
        try:
            return np.linalg.solve(M, b)
        except np.linalg.LinAlgError:
            return np.linalg.lstsq(M, b, rcond=None)[0]

    th = sol(lam0)
    if nz == 0 or np.linalg.norm(th[:nz]) <= radius:
        return th
    norm = _bounded_norm(A + jitter * np.eye(p), b, nz)
    if norm is None:
        def norm(lam):
            return np.linalg.norm(sol(lam)[:nz])
    scale = np.trace(A[:nz, :nz]) / nz + 1e-30
    lo, hi = math.log10(max(lam0 / scale, 1e-12)), 8.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if norm(scale * 10.0 ** mid) > radius:
            lo = mid
        else:
            hi = mid
    return sol(scale * 10.0 ** hi)


def _bounded_norm(A, b, nz):
    """λ ↦ ‖θ(λ)[:nz]‖ for (A + λ D) θ = b, D the projector on the first nz coordinates, from
    one eigendecomposition of the Schur complement; None where the free block is singular."""
    Azz, Azw, Aww = A[:nz, :nz], A[:nz, nz:], A[nz:, nz:]
    bz, bw = b[:nz], b[nz:]
    if Aww.size:
        try:
            K = np.linalg.solve(Aww, np.column_stack([Azw.T, bw]))
        except np.linalg.LinAlgError:
            return None
        S = Azz - Azw @ K[:, :nz]
        c = bz - Azw @ K[:, nz]
    else:
        S, c = Azz, bz
    lam_s, Q = np.linalg.eigh(0.5 * (S + S.T))
    u2 = (Q.T @ c) ** 2

    def norm(lam):
        return math.sqrt(float(np.sum(u2 / (lam_s + lam) ** 2)))
    return norm


@dataclass
class _Model:
    """One axis's model: a prediction (linear effects applied), the baseline, extra columns."""

    pred: np.ndarray  # (K,) mean prediction with the linear effects
    extra: np.ndarray  # (K, q) additive columns, free weights
    theta: np.ndarray = None  # [z; w]
    resid: np.ndarray = None  # (K,) with the plant draw
    resid_mean: np.ndarray = None  # (K,) without it (the profile's mean prediction)
    n_hold: int = 0
    w_mean: np.ndarray = None  # (q,) weights of ``extra`` fitted without the draw
    lag_s: float | None = None  # the twin's lag error fitted with them (``_lag_column``)


class _Axis:
    def __init__(self, ax, cmd, meas, phys: AxisPhysics, ts_s, rows_fit, rows_hold):
        self.ax, self.cmd, self.meas, self.phys, self.ts = ax, cmd, meas, phys, ts_s
        self.fit, self.hold = rows_fit, rows_hold
        self.p0 = respond(cmd, phys.mean)
        L = phys.factor
        r = L.shape[1] if L.ndim == 2 else 0
        dev = cmd - cmd[0]
        self.B = (np.column_stack([respond(dev, L[:, j]) - 0.0 for j in range(r)])
                  if r else np.zeros((cmd.size, 0)))
        self.radius = math.sqrt(stats.chi2.ppf(DRAW_QUANTILE, r)) if r else 0.0
        # the draw's prior z ~ N(0, I) against white measurement noise σ²: MAP adds σ²‖z‖²
        self.prior = noise_floor_mm(meas - self.p0) ** 2
        self.lag, self.lag_sd = _lag_column(self.p0, phys, ts_s)

    @functools.cached_property
    def cmd_acc(self) -> np.ndarray:
        """The commanded acceleration, mm/s² (the ring bar's and cross_coupling's input)."""
        return np.gradient(np.gradient(self.cmd, self.ts), self.ts)

    def fit_model(self, pred, extra, lag: bool = False) -> _Model:
        """Fit the draw z (bounded, with its prior) and the free weights on the fit rows.

        The prior z ~ N(0, I) enters as λ‖z‖² with λ the residual's variance per *effective*
        sample, MSE·N/N_eff: the residual is coloured, so its N samples carry the information
        of N_eff independent ones. Without this the data would always win and the draw would
        soak up any effect that resembles a stiffer or softer machine (a friction lag looks
        like a longer rotor lag at constant speed); with it, the draw moves only as far as the
        evidence of the data outweighs its prior. λ from a first fit at the white-noise floor,
        then one refit. ``lag``: the mean fit also carries the twin's lag error
        (``_lag_column``), with its prior."""
        X = np.hstack([self.B, extra]) if extra.size else self.B
        y = self.meas - pred
        nz = self.B.shape[1]
        if not X.shape[1]:
            return self._model(pred, extra, np.zeros(0), y, y, np.zeros(extra.shape[1]))
        th = self._map(X, y, nz, self.radius)
        resid = y - X @ th
        # the effect's weights against the twin's mean physics (no draw): what the extended
        # profile predicts with, and what is reported (module docstring, 4)
        nl = self.lag.shape[1] if lag else 0
        free = np.hstack([self.lag, extra]) if nl else extra
        if free.size:
            w = self._map(free, y, nl, math.inf)
            resid_mean = y - free @ w
        else:
            w, resid_mean = np.zeros(0), y
        m = self._model(pred, extra, th, resid, resid_mean, w[nl:])
        m.lag_s = float(w[0] * self.lag_sd) if nl else None
        return m

    def _map(self, X, y, nz, radius):
        """θ fitted on the fit rows, ‖θ[:nz]‖ ≤ radius with the prior θ[:nz] ~ N(0, I)."""
        Xf, yf = X[self.fit], y[self.fit]
        G, b = Xf.T @ Xf, Xf.T @ yf
        th = _solve_bounded(G, b, nz, radius, self.prior)
        if nz:
            rf = yf - Xf @ th
            lam = float(rf @ rf) / rf.size * rf.size / _n_eff(rf)
            if lam > self.prior:
                th = _solve_bounded(G, b, nz, radius, lam)
        return th

    def _model(self, pred, extra, th, resid, resid_mean, w_mean=None) -> _Model:
        n = resid.size
        return _Model(pred, extra if extra.size else np.zeros((n, 0)), th, resid, resid_mean,
                      n_hold=len(range(*self.hold.indices(n))),
                      w_mean=np.zeros(0) if w_mean is None else w_mean)

    def ss(self, m: _Model, part) -> float:
        r = m.resid[part]
        return float(r @ r)


def _lag_column(p0, phys: AxisPhysics, ts_s):
    """((K, 1) or (K, 0), σ_τ): the twin's velocity lag error as a regressor, on an axis with
    integral action only: −σ_τ·dx̂/dt (a lag τ = σ_τ·w adds −τ·v̂), prior w ~ N(0, 1).

    Such a loop (a servo's PID) follows a ramp without a steady lag; its FRFs, none below their
    first bin, leave the fitted response's lag (its centroid Σ t·h̄) free, and a lag error
    τ·v looks like a backlash's b/2·sign(v) on steady motion. σ_τ = ‖tᵀL‖: the spread the
    profile's own plant draw gives the centroid (tests/foreign servo_screw: the mean's error
    was within 1 σ_τ on every axis)."""
    if not phys.integral_action or not phys.factor.shape[1]:
        return np.zeros((p0.size, 0)), 0.0
    t = np.arange(phys.mean.size) * ts_s
    sd = float(np.linalg.norm(t @ phys.factor))
    return lag_regressor(p0, ts_s)[:, None] * sd, sd


# ---------------------------------------------------------------------------------------------
# relations and spectrum (reported, not used for the decision)


def _relations(ax, r, cmd, pred, ts_s):
    x = cmd[ax]
    v = np.gradient(x, ts_s)
    a = np.gradient(v, ts_s)
    other = "y" if ax == "x" else "x"

    def corr(u):
        su, sr = np.std(u), np.std(r)
        return float(np.mean((u - u.mean()) * (r - r.mean())) / (su * sr)) if su > 0 and sr > 0 else 0.0

    return {"velocity": corr(v), "velocity_sign": corr(np.sign(v)), "acceleration": corr(a),
            "position": corr(x), "other_axis": corr(cmd[other]),
            "lag_s": float(-np.sum(r * v) / np.sum(v * v)) if np.any(v) else 0.0}


#: below this frequency, Hz, a leftover is slow (a drift: ``leftover``)
SLOW_HZ = 1.0
#: a leftover is significant when the part of it that is not noise is this many times the
#: sensor's noise (and ``MIN_EFFECT_RMS_MM``): an RMS of 1.8 σ; clean logs of machines whose
#: twins match them stay within 1.4 σ (``leftover``)
LEFTOVER_EXCESS = 1.5


def leftover(r: np.ndarray, ts_s: float, mode_hz: float | None = None) -> dict:
    """What the model leaves on the held-out part ``r`` (measured − the twin with the named
    effects and the plant draw, its dominant mode moved inside the members' band where that
    fits better: ``_absorb_mode``), against the sensor's noise there (``noise_floor_mm``: white
    noise is all a perfect model leaves). ``excess_mm`` = √(RMS² − σ²), the part that is
    not noise; ``significant`` when it is at least ``LEFTOVER_EXCESS``·σ and
    ``MIN_EFFECT_RMS_MM`` (an RMS of 1.8 σ or more: on 81 clean logs of 27 drawn non-corexy
    foreign machines whose twins match them, RMS/σ stayed ≤ 1.40, docs/diagnose.md). Its
    character: ``slow_share``, the share of its power below ``SLOW_HZ`` (a drift: thermal
    growth, a creeping sensor), and the largest spectral peak above it (``peak_hz``,
    ``peak_mm``), beside the profile's dominant mode ``mode_hz`` (what is left excites it,
    or the mode is not where the profile puts it: the sentence states the fact, not a
    cause)."""
    r = np.asarray(r, float)
    rms = _rms(r)
    sigma = noise_floor_mm(r)
    excess = math.sqrt(max(rms * rms - sigma * sigma, 0.0))
    P = np.abs(np.fft.rfft(r)) ** 2
    f = np.fft.rfftfreq(r.size, ts_s)
    slow = float(P[f < SLOW_HZ].sum() / P.sum()) if P.sum() > 0 else 0.0
    peak = _spectrum(r, ts_s, n_peaks=1) if r.size > 8 else []
    return {"rms_mm": rms, "noise_mm": sigma, "excess_mm": excess,
            "significant": bool(excess >= max(LEFTOVER_EXCESS * sigma, MIN_EFFECT_RMS_MM)),
            "slow_share": slow,
            "peak_hz": peak[0]["frequency_hz"] if peak else None,
            "peak_mm": peak[0]["amplitude_mm"] if peak else None,
            "mode_hz": None if mode_hz is None else float(mode_hz)}


def leftover_sentence(ax: str, lo: dict) -> str:
    """One line for the CLI on a significant ``leftover``."""
    head = (f"{ax}: {lo['rms_mm'] * 1e3:.2f} µm RMS on the held-out part where the sensor's "
            f"noise is {lo['noise_mm'] * 1e3:.2f} µm: {lo['excess_mm'] * 1e3:.2f} µm no "
            f"named effect explains")
    if lo["slow_share"] >= 0.5:
        return (head + f"; {100 * lo['slow_share']:.0f} % of it below {SLOW_HZ:g} Hz: a drift "
                "(thermal growth, a sensor that creeps, a belt slipping)?")
    if lo["peak_hz"] is None:
        return head
    out = head + f"; its largest part at {lo['peak_hz']:.1f} Hz ({lo['peak_mm'] * 1e3:.2f} µm)"
    m = lo.get("mode_hz")
    if m and abs(lo["peak_hz"] - m) <= 0.3 * m:
        out += f", near the profile's {m:.1f} Hz mode (the mode rings with what is left)"
    return out


def _spectrum(r, ts_s, n_peaks=3):
    n = r.size
    R = np.abs(np.fft.rfft((r - r.mean()) * np.hanning(n))) * 4.0 / n
    f = np.fft.rfftfreq(n, ts_s)
    R[f < 1.0] = 0.0
    idx = []
    for i in np.argsort(R)[::-1]:
        if all(abs(f[i] - f[j]) > 2.0 for j in idx):
            idx.append(i)
        if len(idx) == n_peaks:
            break
    return [{"frequency_hz": float(f[i]), "amplitude_mm": float(R[i])} for i in idx]


# ---------------------------------------------------------------------------------------------


def warmup_samples(cmd_mm: np.ndarray, ts_s: float, n_taps: int) -> int:
    """Samples whose prediction depends on motion before the log began: n_taps when the log
    starts moving (a log cut mid-print), else 0. The twin is causal: nothing else is lost."""
    c = np.asarray(cmd_mm, float)[:, :2]
    if c.shape[0] < 2:
        return 0
    v0 = np.max(np.abs(c[1] - c[0])) / ts_s
    return int(min(n_taps, c.shape[0] // 2)) if v0 > fx.REST_SPEED_MM_S * 1e3 else 0


def diagnose_arrays(cmd_mm: np.ndarray, meas_mm: np.ndarray, ts_s: float, impulse: dict, *,
                    fit_fraction: float = FIT_FRACTION, warmup: int | None = None) -> Diagnosis:
    """Diagnose one log (module docstring).

    Args:
        cmd_mm: (K, ≥2) commanded X, Y. meas_mm: (K, ≥2) measured X, Y, mm.
        impulse: axis -> AxisPhysics (``axis_physics``) or (mean (n,), factor (n, r) | None).
        warmup: samples left out at the start (default ``warmup_samples``).
    """
    phys = _as_physics(impulse, ts_s)
    K = cmd_mm.shape[0]
    n_taps = max(p.mean.size for p in phys.values())
    w0 = warmup_samples(cmd_mm, ts_s, n_taps) if warmup is None else int(warmup)
    nfit = w0 + int(round((K - w0) * fit_fraction))
    fit, hold = slice(w0, nfit), slice(nfit, K)
    cmd = {ax: np.asarray(cmd_mm[:, i], float) for i, ax in enumerate(AXES)}
    meas = {ax: np.asarray(meas_mm[:, i], float) for i, ax in enumerate(AXES)}
    A = {ax: _Axis(ax, cmd[ax], meas[ax], phys[ax], ts_s, fit, hold) for ax in AXES}
    resid0 = {ax: meas[ax] - A[ax].p0 for ax in AXES}
    base = {ax: A[ax].fit_model(A[ax].p0, np.zeros((K, 0))) for ax in AXES}
    first = dict(base)
    # what an effect must beat: the baseline, or the dominant mode moved within the profile's
    # own spread where that fits better (``_absorb_mode``); candidates are built on the baseline
    bar = {ax: _absorb_mode(A[ax], base[ax]) for ax in AXES}
    named: list[Candidate] = []
    # kind -> the parameters named of it, per axis
    named_kinds: dict = {ax: {} for ax in AXES}
    all_cands: list[Candidate] = []
    crit_hold = float(stats.chi2.isf(ALPHA, 1))
    for round_ in range(MAX_EFFECTS):
        raw = []
        for ax in AXES:
            other = "y" if ax == "x" else "x"
            for kind, form, params, m, n_tried, q in _candidates(
                    A[ax], base[ax], named_kinds[ax], A[other], base[other]):
                if kind in named_kinds[ax] and kind not in REPEATABLE:
                    continue
                raw.append((ax, kind, form, params, m, n_tried, q))
        cands = _judge(raw, A, bar, base, fit, hold, K - nfit, crit_hold)
        if round_ == 0:
            all_cands = cands
        pick = _choose(cands, fit, hold, K - nfit, crit_hold)
        if pick is None:
            break
        named.append(pick)
        named_kinds[pick.axis].setdefault(pick.kind, []).append(pick.params)
        if pick.kind in ("friction", "backlash"):  # one of the two per axis (module docstring)
            for k in ("friction", "backlash"):
                named_kinds[pick.axis].setdefault(k, [])
        base[pick.axis] = pick.model
        bar[pick.axis] = _absorb_mode(A[pick.axis], pick.model, named_kinds[pick.axis])

    hold_idx = np.arange(nfit, K)
    before = {ax: _rms(resid0[ax][hold_idx]) for ax in AXES}
    after = {ax: _rms(base[ax].resid_mean[hold_idx]) for ax in AXES}
    with_draw = {ax: _rms(base[ax].resid[hold_idx]) for ax in AXES}
    draw_only = {ax: _rms(first[ax].resid[hold_idx]) for ax in AXES}
    if named:
        effects = [c.to_dict() for c in named]
    else:
        worst = max(AXES, key=lambda a: before[a])
        top = all_cands[0] if all_cands else None
        effects = [{"kind": "none", "axis": worst, "params": {},
                    "confidence": float(1.0 - max(top.fraction, 0.0) if top else 1.0)}]
    full_rms = {ax: _rms(resid0[ax][w0:]) for ax in AXES}
    # what is left once the known uncertainty has explained what it can: the bar (the draw,
    # or the dominant mode moved inside the members' band) with the named effects
    left = {ax: leftover(bar[ax].resid[hold_idx], ts_s, phys[ax].mode_hz) for ax in AXES}
    return Diagnosis(
        residual_rms_mm=full_rms, effects=effects,
        holdout_rms_mm={"before": before, "after": after,
                        "plant_draw_only": draw_only, "after_with_plant_draw": with_draw},
        candidates=all_cands,
        relations={ax: _relations(ax, resid0[ax][w0:], {a: cmd[a][w0:] for a in AXES}, None, ts_s)
                   for ax in AXES},
        spectrum={ax: _spectrum(resid0[ax][w0:], ts_s) for ax in AXES}, fit_samples=nfit,
        warmup_samples=w0, leftover=left,
        residual_mm=np.column_stack([resid0[ax] for ax in AXES]),
        corrected_mm=np.column_stack([base[ax].resid for ax in AXES]), named=named)


def _judge(raw, A: dict, bar: dict, base: dict, fit, hold, n_hold: int,
           crit_hold: float) -> list[Candidate]:
    """Each raw candidate (axis, kind, form, params, model, n_tried, q) tested against what an
    effect on its axis must beat, on the fit part (χ²(q) at ALPHA Bonferroni-divided over
    every parameter value tried this round, M) and on the held-out part; most explained on
    the fit part first."""
    M = sum(r[5] for r in raw)
    cands = []
    rings = {}
    for ax, kind, form, params, m, n_tried, q in raw:
        a = A[ax]
        other = A["y" if ax == "x" else "x"]
        # the bar on each part is the better of the two (a mode moved on the fit part may
        # fit the held-out part worse: the test must not get easier for it)
        bars = [bar[ax], base[ax]]
        if kind == "periodic_time":
            ring = _ring_bar(a, other, bar[ax], params["frequency_hz"])
            if ring is not None:
                bars.append(ring)
        ss0_f = min(a.ss(b, fit) for b in bars)
        ss0_h = min(a.ss(b, hold) for b in bars)
        ss1_f, ss1_h = a.ss(m, fit), a.ss(m, hold)
        ne_f = _n_eff(m.resid[fit])
        ne_h = _n_eff(m.resid[hold]) if n_hold > 3 else 1.0
        t_fit = (ss0_f - ss1_f) / max(ss1_f / ne_f, 1e-30)
        t_hold = (ss0_h - ss1_h) / max(ss1_h / ne_h, 1e-30)
        crit_fit = float(stats.chi2.isf(ALPHA / max(M, 1), q))
        frac = (ss0_h - ss1_h) / ss0_h if ss0_h > 0 else 0.0
        ring_frac = None
        if t_fit > crit_fit and t_hold > crit_hold and frac < MIN_EXPLAINED:
            if ax not in rings:  # the ring's columns and bars, once per axis and round
                cols = _ring_columns(a, other, a.phys.mode_hz or 0.0, base[ax].extra)
                rings[ax] = (cols, [] if cols is None else
                             [_with_columns(a, b, cols) for b in (bar[ax], base[ax])])
            ring_frac = _ring_relevance(a, m, *rings[ax], crit_fit, crit_hold)
        cands.append(Candidate(kind, ax, params, form, ss1_f, ss1_h, ss0_f - ss1_f,
                               ss0_h - ss1_h, frac, float(t_fit), float(t_hold), crit_fit,
                               crit_hold, m, ring_frac))
    cands.sort(key=lambda c: -c.explained_fit)
    return cands


def _ring_relevance(a: _Axis, m: _Model, cols: np.ndarray | None, rings: list,
                    crit_fit: float, crit_hold: float) -> float | None:
    """The share of the held-out SS a candidate explains beyond its axis's mode ring, where it
    passes both tests against the ring too (its model with the ring's columns ``cols`` —
    ``_ring_columns`` at the mode, driven by the model so far's effects — against the better
    ring bar, ``rings``); else None.

    Relevance asks an effect to explain ``MIN_EXPLAINED`` of what is left, and on an axis
    with a lightly damped mode most of what is left may be that mode's ring — the plant's
    mode a little off the twin's, or a corexy's belt cross-talk, which the known physics
    holds with its residue, phase and cross-talk unknown (``_ring_bar``). There the share
    is taken of what the ring leaves, and the candidate must beat the ring on both parts
    (a candidate that only fits part of the ring fails that). Foreign corexy 610 (belts
    38.9/38.2 Hz, ζ 0.026): the ring leaves y 4.2 µm of 16.7 on a clean Benchy layer, and an
    8.3 µm eccentricity (λ 6.94 mm) explained 14 % of what the bar left: `none` before."""
    if cols is None or not rings:
        return None
    rm = _with_columns(a, m, cols)
    fit, hold = a.fit, a.hold
    r0f, r0h = min(a.ss(b, fit) for b in rings), min(a.ss(b, hold) for b in rings)
    r1f, r1h = a.ss(rm, fit), a.ss(rm, hold)
    t_f = (r0f - r1f) / max(r1f / _n_eff(rm.resid[fit]), 1e-30)
    t_h = (r0h - r1h) / max(r1h / _n_eff(rm.resid[hold]), 1e-30)
    if t_f <= crit_fit or t_h <= crit_hold or r0h <= 0:
        return None
    return float((r0h - r1h) / r0h)


def _choose(cands: list, fit, hold, n_hold: int, crit_hold: float) -> Candidate | None:
    """The effect a round names among the passing candidates, or None."""
    passing = [c for c in cands if c.passes]
    if not passing:
        return None
    pick = passing[0]
    # candidates the fit part cannot tell from the leader (their ΔSS below the bar an effect
    # must clear, crit_fit in units of the leader's noise: e.g. a delay, a friction and a
    # backlash are all a constant lag on a stretch of steady motion) are told apart by the
    # held-out part, which none was fitted on
    ne_f = _n_eff(pick.model.resid[fit])
    noise_f = pick.ss_fit / max(ne_f, 1e-30)
    tied = [c for c in passing if (c.ss_fit - pick.ss_fit) <= c.crit_fit * noise_f]
    pick = max(tied, key=lambda c: c.explained_hold)
    if pick.kind in ("friction", "backlash"):
        rival = next((c for c in cands if c.axis == pick.axis and c.kind ==
                      ("backlash" if pick.kind == "friction" else "friction")), None)
        # the two exclude each other on an axis; where the fit part preferred one and the
        # held-out part, which neither was fitted on, prefers the other significantly (the
        # held-out statistic between the two), the held-out part decides: a corexy's friction
        # (626 y) led as a backlash by 1573 to 1264 on the fit part, explaining 136 against
        # 720 held out
        if rival is not None and rival.passes:
            ne_r = _n_eff(rival.model.resid[hold]) if n_hold > 3 else 1.0
            if (pick.ss_hold - rival.ss_hold) / max(rival.ss_hold / ne_r, 1e-30) > crit_hold:
                pick, rival = rival, pick
        if rival is not None:
            ne_h = _n_eff(pick.model.resid[hold]) if n_hold > 3 else 1.0
            t = (rival.ss_hold - pick.ss_hold) / max(pick.ss_hold / ne_h, 1e-30)
            if t <= crit_hold:
                # a friction that sticks and a backlash on the response are one model (a play
                # on the response): which one leads is a hair of the held-out part, so one
                # convention, the backlash named (its form came first: our virtual machine's
                # play) and the friction stated as the tie
                if (pick.kind, pick.form, rival.kind, rival.form) == \
                        ("friction", "stick", "backlash", "output") and rival.passes:
                    pick, rival = rival, pick
                pick.params = {**pick.params, "tie": {"kind": rival.kind,
                                                      "params": dict(rival.params)}}
    return pick


def _absorb_mode(a: _Axis, plain: _Model, named_kinds=()) -> _Model:
    """The bar an effect on one axis must clear: the plant draw z (``plain``) or, with modal
    physics, the dominant mode anywhere in the band the profile's own measurements put it,
    whichever fits the fit part better (module docstring, 1).

    The draw's directions L are the first-order change of the impulse response about the mean.
    For a lightly damped mode (ζ ≈ 0.03 rings for ~6 periods) a 1–2 % move of its frequency is
    not first order: the phase error grows along the ringing, and L leaves a residual a
    ``resonance_shift`` fitted *inside* the members' band then explains (a foreign belt machine
    with members at 49.0–50.4 Hz: every clean log was named a shift to 49.7 Hz). So the mode is
    scanned over the band the known uncertainty allows (``AxisPhysics.mode_scan_hz``: the
    members' band widened by half its width on each side, the plant of the logs not being one
    of the measurements): the known uncertainty explains the mismatch before any effect may.
    A true shift (a mass change of 25 %: −11 %) lies far outside. Only a mode that rings
    (ζ < ``RINGING_ZETA``) is scanned: a heavily damped one is linear enough in its frequency
    for L, and is poorly located by its members (a servo's: 19–48 Hz). Candidates
    stay built on the profile's mean (what ``diagnose -o`` writes), so the moved mode never
    leaks into a named effect's parameters or the after figures. After an effect is named the
    bar is its model with the mode moved again (the effect's columns refitted): a second effect
    on the axis must beat that too — unless the effect named was the mode's own shift."""
    scan = a.phys.mode_scan_hz
    if (a.phys.shifted is None or scan is None or a.cmd.size < 8
            or "resonance_shift" in named_kinds):
        return plain
    lo, hi = scan
    if hi - lo <= 2e-6 * hi:
        return plain

    def moved(f1):
        return a.fit_model(plain.pred + respond(a.cmd, a.phys.shifted(f1)) - a.p0, plain.extra,
                           plain.lag_s is not None)

    def score(f1):
        return -a.ss(moved(f1), a.fit)

    grid = np.linspace(lo, hi, 9)
    f1, v, _ = _scan(score, grid, refine=False)
    f1, v = _refine(score, grid, f1, v, rounds=2, points=5)
    return moved(f1) if -v < a.ss(plain, a.fit) else plain


def _ring_bar(a: _Axis, other: _Axis, bar: _Model, f_hz: float,
              drivers: np.ndarray | None = None) -> _Model | None:
    """What a ``periodic_time`` near a ringing mode must beat besides the bar: the mode ringing
    at that frequency as the commands excite it (``RING_BAND``; None elsewhere).

    A lightly damped mode that the twin places a little off, or a corexy's belt cross-talk
    ((G_A − G_B)/2 times the other axis's command, a beat of two modes 2–3 % apart), leaves a
    residual that rings at the mode whenever either axis accelerates. On a butterfly, whose
    accelerations recur lap after lap, a sinusoid of fixed phase near the mode fits that ring
    on the fit part and on the held-out part alike: foreign corexy machines (tests/foreign,
    seeds 0 and 18) had a 43 µm and a 4.9 µm "fan" named at 25.2 and 34.4 Hz, their belts at
    25.7/26.5 and 35.7/36.9 Hz. A fan is not driven by the motion: its sinusoid runs on at
    rest and through any path. So the ring — each axis's commanded acceleration through one
    mode at the candidate's frequency and the mode's damping, both quadratures, free weights
    (the known physics with its residue, phase and cross-talk unknown), and through that
    mode's derivative in its frequency (t·e^(−ζωt) in both quadratures: the plant's mode a
    little off the twin's, a ring whose phase drifts as it decays) — joins the bar: a fan is
    named only where a sinusoid beats the motion's own ringing too. Without the derivative
    a corexy whose belts (38.9/38.2 Hz, ζ 0.026) its five FRFs place on a 2 Hz grid had a
    2.7 µm "fan" at 37.9 Hz named on a clean rose (tests/foreign, corexy610more).

    The named effects drive the mode too: each of ``drivers``' columns (default the bar's
    effect columns), differentiated in time, through the same taps — a Coulomb force's step
    at each reversal rings the mode, and the twin's form of it leaves that ring a little off:
    a belt machine's friction (tests/foreign, 624, x's mode 23.4 Hz) had a 2.7 µm "fan" at
    22.9 Hz named after it on a butterfly.

    The other axis's ringing mode counts as this axis's: its carriage's ring reaches this axis
    through the frame, and a frame force's regressor a little off it left a belt machine
    (tests/foreign 23, x 30.3 Hz ζ 0.034) with a 4.2 µm "fan" at 30.8 Hz on y beside the
    cross-coupling, and a second at 29.0 Hz once periodic_time could come twice."""
    cols = _ring_columns(a, other, f_hz, bar.extra if drivers is None else drivers)
    return None if cols is None else _with_columns(a, bar, cols)


def _with_columns(a: _Axis, m: _Model, cols: np.ndarray) -> _Model:
    """``m`` refitted with ``cols`` as further free columns."""
    return a.fit_model(m.pred, np.hstack([m.extra, cols]), m.lag_s is not None)


def _ring_columns(a: _Axis, other: _Axis, f_hz: float, drivers: np.ndarray) -> np.ndarray | None:
    """(K, c) the ring's columns of ``_ring_bar`` at ``f_hz`` (each RMS 1 on the fit part), or
    None off the band of either axis's ringing mode."""
    if a.cmd.size < 8:
        return None
    # this axis's ringing mode, or the other's: its carriage's ring reaches this axis through
    # the frame (a cross-coupling's form a little off it)
    zeta = None
    for ph in (a.phys, other.phys):
        span, z = ph.mode_span_hz, ph.mode_zeta
        if span is not None and z is not None and \
                span[0] * (1 - RING_BAND) <= f_hz <= span[1] * (1 + RING_BAND):
            zeta = z
            break
    if zeta is None:
        return None
    n = a.phys.mean.size
    t = np.arange(n) * a.ts
    w = 2 * np.pi * f_hz
    env = np.exp(-zeta * w * t)
    wd = w * math.sqrt(max(1 - zeta * zeta, 1e-6))
    taps = (env * np.sin(wd * t), env * np.cos(wd * t),
            t * env * np.sin(wd * t), t * env * np.cos(wd * t))
    cols = []
    for u in (a.cmd_acc, other.cmd_acc, *(np.gradient(c, a.ts) for c in drivers.T)):
        for h in taps:
            g = oaconvolve(u, h)[:u.size]
            s = float(np.sqrt(np.mean(g[a.fit] ** 2)))
            if s > 0:
                cols.append(g / s)
    return np.column_stack(cols) if cols else None


def _rms(r) -> float:
    return float(np.sqrt(np.mean(np.square(r)))) if np.size(r) else 0.0


def diagnose_log(log, profile, *, fit_fraction: float = FIT_FRACTION,
                 warmup: int | None = None) -> Diagnosis:
    """Diagnose a MotionLog against a profile's twin. The held-out ``before``/``after`` RMS are
    those of the twin's mean prediction (``predict --no-learn``) with the profile as is and
    with the profile ``extend_profile`` writes from this diagnosis: what ``diagnose -o`` writes
    is what was measured. ``after_fitted`` keeps the fitted phase of a periodic_time effect
    (this log only; the profile carries a fan as variance)."""
    if not np.isclose(log.ts_s, profile.ts_s, rtol=1e-3):
        raise LogError(f"log Ts={log.ts_s:.6g} s differs from the profile {profile.name!r} "
                       f"Ts={profile.ts_s:g} s; wrong machine, or resample the log")
    if warmup is None:
        warmup = getattr(log, "warmup", None)
    # the twin acts on what the machine received: the log's commands through the firmware's
    # input shaper (twin.physics.log_machine_command)
    cmd = log_machine_command(profile, log)
    d = diagnose_arrays(cmd, log.pos_mm, log.ts_s, axis_physics(profile),
                        fit_fraction=fit_fraction, warmup=warmup)
    hold = slice(d.fit_samples, log.cmd_mm.shape[0])
    before = twin_mean_mm(profile, cmd)
    d.holdout_rms_mm["after_fitted"] = d.holdout_rms_mm["after"]
    d.holdout_rms_mm["before"] = {ax: _rms(log.pos_mm[hold, i] - before[hold, i])
                                  for i, ax in enumerate(AXES)}
    if d.named:
        ext = extend_profile(profile, d.effects)
        after = twin_mean_mm(ext, cmd)
        d.holdout_rms_mm["after"] = {ax: _rms(log.pos_mm[hold, i] - after[hold, i])
                                     for i, ax in enumerate(AXES)}
    else:
        d.holdout_rms_mm["after"] = dict(d.holdout_rms_mm["before"])
    return d


def twin_mean_mm(profile, cmd_mm: np.ndarray) -> np.ndarray:
    """(K, 2) the twin's open-loop mean prediction of X, Y (``predict --no-learn``), with the
    profile's extensions, for the machine's input ``cmd_mm`` (twin.physics.machine_command)."""
    cmd = np.asarray(cmd_mm, float)
    off = mean_offsets(profile, cmd)
    return np.column_stack([axis_twin(profile, ax).run(cmd[:, i], None, learn=False,
                                                       offset_mm=off[:, i])[0]
                            for i, ax in enumerate(AXES)])
