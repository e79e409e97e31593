"""Diagnose what the twin gets wrong on a log, name the cause, extend the model (issue 6).

Method (pure numerics on arrays; the CLI ``gcode-feedopt diagnose`` reads the files):

1. **Prediction.** Per axis the twin's mean impulse response h̄ (``twin.frf.impulse_response``,
   scaled to unit DC gain as the plant does) gives x̂ = x_0 + h̄ * (x_cmd − x_0). The twin's
   *known* uncertainty (the FRF spread, Σ_h = L Lᵀ) is allowed for by a **baseline** fit: the
   columns of L convolved with the command are regressors whose weights say which machine of
   the population this is (what the twin's online learning finds, see twin.model._run_joint).
   The residual r = measured − (x̂ + baseline) is what the twin gets wrong.
2. **Catalogue.** Each kind of ``vm.effects`` implies regressors on the residual:
   ``periodic_time`` sin/cos(2πft) (f scanned from the residual spectrum, refined);
   ``periodic_position`` sin/cos(2πx_cmd/λ) (λ scanned 1–60 mm: longer ones mimic a gain over a 200 mm bed); ``backlash`` play(x̂, b) − x̂
   (b scanned); ``friction`` −sign(v_cmd); ``delay`` x̂(t − d) − x̂(t) (d scanned);
   ``gain`` x̂ (about the machine origin); ``resonance_shift`` h̄ with its mode moved to f1,
   convolved, minus x̂ (f1 scanned); ``cross_coupling`` the other axis's x̂ − x̂_0.
   Every scan and every weight is fitted on the **first part** of the log only
   (``fit_fraction``); candidates are ranked by the residual sum of squares they explain.
3. **Decision.** The best candidate is named when it explains at least ``MIN_EXPLAINED`` of the
   fit-part residual and at least ``MIN_EFFECT_RMS_MM`` RMS, its chi-square-like gain ΔSS/(SS_after/N) exceeds ``MIN_SCORE`` (many
   scanned parameters make a few tens likely by chance on pure noise) and it lowers the
   held-out RMS by ``MIN_HOLDOUT_GAIN``; otherwise ``none``. Up to ``MAX_EFFECTS`` effects are
   taken greedily (the next one on what the first leaves).
4. **Held-out gain.** The named effects' regressors, with their fitted weights, are applied to
   the held-out rest of the log: prediction RMS before/after per axis.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..vm import effects as fx
from ..vm.plant import respond

AXES = ("x", "y")
KINDS = ("periodic_time", "periodic_position", "backlash", "friction", "delay", "gain",
         "resonance_shift", "cross_coupling")
#: Fraction of the fit-part residual sum of squares a candidate must explain to be named.
MIN_EXPLAINED = 0.2
#: ΔSS / (SS_after / N_fit) a named candidate must exceed (scan over ~10³ parameter values on
#: white noise gives ≲ 30; see tests/closedloop/test_diagnose.py clean logs).
MIN_SCORE = 200.0
#: Held-out RMS must fall by at least this fraction for an effect to be named.
MIN_HOLDOUT_GAIN = 0.1
MAX_EFFECTS = 2
#: An effect must explain at least this RMS on the fit part to be named, mm (1 µm: 1/100 of a
#: printer's 0.1 mm tolerance; a drawn plant's difference from the twin's mean is about this).
MIN_EFFECT_RMS_MM = 0.001
FIT_FRACTION = 0.6


@dataclass
class Candidate:
    kind: str
    axis: str
    params: dict
    explained_ss: float  # fit part, mm²
    fraction: float  # of the fit-part residual SS
    score: float
    G: np.ndarray = field(repr=False, default=None)  # (K, p) regressors over the whole log
    w: np.ndarray = field(repr=False, default=None)  # (p,) weights fitted on the fit part

    def to_dict(self, confidence: float | None = None) -> dict:
        return {"kind": self.kind, "axis": self.axis, "params": self.params,
                "confidence": float(self.fraction if confidence is None else confidence),
                "explained_fraction": float(self.fraction)}


@dataclass
class Diagnosis:
    residual_rms_mm: dict
    effects: list
    holdout_rms_mm: dict
    candidates: list
    relations: dict
    spectrum: dict
    fit_samples: int
    residual_mm: np.ndarray = field(repr=False, default=None)  # (K, 2) before
    corrected_mm: np.ndarray = field(repr=False, default=None)  # (K, 2) after (whole log)
    named: list = field(repr=False, default_factory=list)  # accepted Candidates

    def to_dict(self) -> dict:
        return {"residual_rms_mm": self.residual_rms_mm, "effects": self.effects,
                "holdout_rms_mm": self.holdout_rms_mm,
                "candidates": [c.to_dict() for c in self.candidates],
                "relations": self.relations, "spectrum": self.spectrum,
                "fit_samples": self.fit_samples}


def nominal_impulse(profile) -> dict:
    """axis -> (mean (n,), factor (n, r)) of the twin's impulse response, unit DC gain."""
    from ..twin.physics import axis_impulse

    out = {}
    for ax in AXES:
        ir = axis_impulse(profile, ax)
        s = float(np.sum(ir.mean))
        out[ax] = (np.asarray(ir.mean) / s, np.asarray(ir.factor) / s)
    return out


def _lstsq(G, r):
    w, *_ = np.linalg.lstsq(G, r, rcond=None)
    return w


def _explained(G, r):
    """(explained SS, weights) of least squares of r on the columns of G."""
    w = _lstsq(G, r)
    fit = G @ w
    return float(r @ r - (r - fit) @ (r - fit)), w


def _unit(G, r):
    g = G[:, 0]
    return float(r @ r - (r - g) @ (r - g)), None


def _scan(make, grid, r, nfit, refine=True, unit=False):
    """Best parameter of ``make(p) -> G (K, q)`` over ``grid`` (then a finer grid around it).
    ``unit``: the single regressor enters with weight 1 (the effect's own size is the
    parameter: backlash, delay, resonance shift); a free weight would trade off against it."""
    score = _unit if unit else _explained
    best = (-np.inf, None)
    for p in grid:
        e, _ = score(make(p)[:nfit], r)
        if e > best[0]:
            best = (e, p)
    if refine and best[1] is not None:
        grid = np.asarray(grid, float)
        i = int(np.argmin(np.abs(grid - best[1])))
        lo = grid[max(i - 1, 0)]
        hi = grid[min(i + 1, grid.size - 1)]
        for _ in range(3):
            fine = np.linspace(lo, hi, 21)
            for p in fine:
                e, _ = score(make(p)[:nfit], r)
                if e > best[0]:
                    best = (e, p)
            step = (hi - lo) / 20
            lo, hi = best[1] - step, best[1] + step
    return best[1]


def _candidates(ax, r, nfit, cmd, pred, h, ts_s):
    """All catalogue candidates for one axis, each with its scanned parameter."""
    K = r.size
    t = np.arange(K) * ts_s
    x_cmd = cmd[ax]
    p = pred[ax]
    other = "y" if ax == "x" else "x"
    rf = r[:nfit]
    out = []

    # periodic_time: start from the residual spectrum peak
    n_fft = 1 << int(np.ceil(np.log2(nfit * 4)))
    R = np.abs(np.fft.rfft(rf * np.hanning(nfit), n_fft))
    f = np.fft.rfftfreq(n_fft, ts_s)
    band = (f >= 1.0) & (f <= 0.48 / ts_s)
    f0 = float(f[band][np.argmax(R[band])])
    df = f[1] - f[0]

    def sincos_t(fr):
        return np.column_stack([np.sin(2 * np.pi * fr * t), np.cos(2 * np.pi * fr * t)])

    fr = _scan(sincos_t, np.linspace(f0 - 2 * df, f0 + 2 * df, 9), rf, nfit)
    out.append(("periodic_time", sincos_t, fr, lambda v, w: {
        "frequency_hz": float(v), "amplitude_mm": float(np.hypot(*w))}))

    def sincos_x(lam):
        return np.column_stack([np.sin(2 * np.pi * x_cmd / lam), np.cos(2 * np.pi * x_cmd / lam)])

    lam = _scan(sincos_x, np.geomspace(1.0, 60.0, 300), rf, nfit)
    out.append(("periodic_position", sincos_x, lam, lambda v, w: {
        "wavelength_mm": float(v), "amplitude_mm": float(np.hypot(*w))}))

    def play_g(b):
        return (fx.play(p, b) - p)[:, None]

    b = _scan(play_g, np.geomspace(0.005, 0.5, 30), rf, nfit, unit=True)
    out.append(("backlash", play_g, b, lambda v, w: {"magnitude_mm": float(v)}))

    sgn = -fx.velocity_sign(x_cmd, ts_s)[:, None]
    out.append(("friction", lambda _: sgn, None, lambda v, w: {"amplitude_mm": float(w[0])}))

    def delay_g(d):
        return (fx.delay_signal(p, d, ts_s) - p)[:, None]

    d = _scan(delay_g, np.geomspace(2e-4, 0.05, 40), rf, nfit, unit=True)
    out.append(("delay", delay_g, d, lambda v, w: {"delay_s": float(v)}))

    gp = p[:, None]
    out.append(("gain", lambda _: gp, None, lambda v, w: {"scale": float(1.0 + w[0])}))

    hm = h[ax]
    fmode = fx.dominant_mode_hz(hm, ts_s)

    def shift_g(f1):
        h1 = fx.rescale_impulse_response(hm, f1 / fmode)
        return (respond(x_cmd, h1) - p)[:, None]

    f1 = _scan(shift_g, fmode * np.linspace(0.5, 1.6, 45), rf, nfit, unit=True)
    out.append(("resonance_shift", shift_g, f1, lambda v, w: {"frequency_hz": float(v)}))

    go = (pred[other] - pred[other][0])[:, None]
    out.append(("cross_coupling", lambda _: go, None, lambda v, w: {
        "from_axis": other, "coefficient": float(w[0])}))
    return out


def _relations(ax, r, cmd, pred, ts_s):
    """Correlation of the residual with velocity, its sign, acceleration, position, the other
    axis, and the lag of the measured response against the prediction."""
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


def _spectrum(r, ts_s, n_peaks=3):
    n = r.size
    R = np.abs(np.fft.rfft(r * np.hanning(n))) * 4.0 / n  # sine amplitude (Hann gain 0.5)
    f = np.fft.rfftfreq(n, ts_s)
    R[f < 1.0] = 0.0
    idx = []
    order = np.argsort(R)[::-1]
    for i in order:
        if all(abs(f[i] - f[j]) > 2.0 for j in idx):
            idx.append(i)
        if len(idx) == n_peaks:
            break
    return [{"frequency_hz": float(f[i]), "amplitude_mm": float(R[i])} for i in idx]


def diagnose_arrays(cmd_mm: np.ndarray, meas_mm: np.ndarray, ts_s: float, impulse: dict, *,
                    fit_fraction: float = FIT_FRACTION, known_uncertainty: bool = False) -> Diagnosis:
    """Diagnose one log.

    Args:
        cmd_mm: (K, ≥2) commanded X, Y. meas_mm: (K, ≥2) measured X, Y, mm.
        impulse: axis -> (mean (n,), factor (n, r) or None), the twin's response.
        known_uncertainty: fit the baseline (the FRF spread's directions) first. Off by
            default: measured, the ensemble's directions are free enough to absorb a delay
            or a 15–30 % resonance shift completely (0/6 delays found with it), so the
            diagnosis is made against the twin's mean response.
    """
    K = cmd_mm.shape[0]
    nfit = int(round(K * fit_fraction))
    cmd = {ax: np.asarray(cmd_mm[:, i], float) for i, ax in enumerate(AXES)}
    meas = {ax: np.asarray(meas_mm[:, i], float) for i, ax in enumerate(AXES)}
    h = {ax: impulse[ax][0] for ax in AXES}
    pred, base, resid = {}, {}, {}
    for ax in AXES:
        pred[ax] = respond(cmd[ax], h[ax])
        L = impulse[ax][1]
        r0 = meas[ax] - pred[ax]
        if known_uncertainty and L is not None and L.size:
            B = np.column_stack([respond(cmd[ax] - cmd[ax][0], L[:, j]) - 0.0 for j in range(L.shape[1])])
            base[ax] = B
            wb = _lstsq(B[:nfit], r0[:nfit])
            r0 = r0 - B @ wb
        else:
            base[ax] = np.zeros((K, 0))
        resid[ax] = r0

    named: list[Candidate] = []
    all_cands: list[Candidate] = []
    current = {ax: resid[ax].copy() for ax in AXES}
    Gacc = {ax: base[ax] for ax in AXES}
    before_rms = {ax: float(np.sqrt(np.mean(resid[ax][nfit:] ** 2))) for ax in AXES}
    after_rms = dict(before_rms)
    after_full = {ax: resid[ax].copy() for ax in AXES}
    for round_ in range(MAX_EFFECTS):
        cands = []
        for ax in AXES:
            r = current[ax]
            ss = float(r[:nfit] @ r[:nfit])
            for kind, make, param, describe in _candidates(ax, r, nfit, cmd, pred, h, ts_s):
                G = make(param)
                e, w = _explained(G[:nfit], r[:nfit])
                after = max(ss - e, 1e-30)
                score = e / (after / nfit)
                cands.append(Candidate(kind, ax, describe(param, w), e, e / ss if ss > 0 else 0.0,
                                       float(score), G, w))
        cands.sort(key=lambda c: -c.explained_ss)
        if round_ == 0:
            all_cands = cands
        best = cands[0]
        if (best.fraction < MIN_EXPLAINED or best.score < MIN_SCORE
                or np.sqrt(best.explained_ss / nfit) < MIN_EFFECT_RMS_MM):
            break
        ax = best.axis
        # refit the baseline and the named effects jointly on the fit part
        G = np.column_stack([Gacc[ax], best.G])
        r0 = meas[ax] - pred[ax]
        w = _lstsq(G[:nfit], r0[:nfit])
        new = r0 - G @ w
        new_rms = float(np.sqrt(np.mean(new[nfit:] ** 2)))
        if new_rms > (1 - MIN_HOLDOUT_GAIN) * after_rms[ax]:
            break
        Gacc[ax] = G
        after_rms[ax] = new_rms
        after_full[ax] = new
        current[ax] = new
        # final weights of the effect columns, refit jointly
        best.w = w[-best.G.shape[1]:]
        named.append(best)

    if named:
        effects = [c.to_dict() for c in named]
    else:
        worst = max(AXES, key=lambda a: before_rms[a])
        top = all_cands[0] if all_cands else None
        effects = [{"kind": "none", "axis": worst, "params": {},
                    "confidence": float(1.0 - (top.fraction if top else 0.0))}]
    full_rms = {ax: float(np.sqrt(np.mean(resid[ax] ** 2))) for ax in AXES}
    return Diagnosis(
        residual_rms_mm=full_rms, effects=effects,
        holdout_rms_mm={"before": before_rms, "after": after_rms},
        candidates=all_cands,
        relations={ax: _relations(ax, resid[ax], cmd, pred, ts_s) for ax in AXES},
        spectrum={ax: _spectrum(resid[ax], ts_s) for ax in AXES}, fit_samples=nfit,
        residual_mm=np.column_stack([resid[ax] for ax in AXES]),
        corrected_mm=np.column_stack([after_full[ax] for ax in AXES]), named=named)


def diagnose_log(log, profile, *, fit_fraction: float = FIT_FRACTION) -> Diagnosis:
    """Diagnose an EncoderLog against a profile's twin."""
    from ..errors import LogError

    if not np.isclose(log.ts_s, profile.ts_s, rtol=1e-3):
        raise LogError(f"log Ts={log.ts_s:.6g} s differs from the profile {profile.name!r} "
                       f"Ts={profile.ts_s:g} s; wrong machine, or resample the log")
    return diagnose_arrays(log.cmd_mm, log.pos_mm, log.ts_s, nominal_impulse(profile),
                           fit_fraction=fit_fraction)
