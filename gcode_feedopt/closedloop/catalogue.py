"""The diagnosis's catalogue: each kind's candidate on one axis, its parameter scanned on the
fit part against the model so far (``closedloop.diagnose``'s module docstring lists the kinds
and their forms; ``diagnose_arrays`` tests and names them).

Each kind is one function of a ``_Scorer`` (how a regressor or a prediction scores against the
model so far) returning ``(kind, form, params, model, n_tried, q)``: the fitted model, the
number of parameter values tried (the Bonferroni count of the fit-part test) and the degrees
of freedom of its χ² test.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.fft
from scipy import stats

from ..twin.extensions import integral_sign, relax_sign
from ..twin.physics import RINGING_ZETA
from ..vm import effects as fx
from ..vm.plant import respond

if TYPE_CHECKING:  # the axis and model types are diagnose's; no import at run time
    from .diagnose import _Axis, _Model

#: Friction relaxation time constants scanned, s (0: the lag vanishes as the axis stops).
FRICTION_TAU_S = (0.0, 0.03, 0.1, 0.2, 0.3, 0.5, 1e6)
#: Integral time constants K_p/K_i scanned for a servo's friction (form ``integral``), s.
INTEGRAL_TAU_S = tuple(float(v) for v in np.geomspace(0.005, 0.4, 12))
#: Quasi-static lags scanned for a friction that sticks (form ``stick``), mm: half the widths
#: ``_backlash`` scans.
STICK_MM = np.geomspace(0.0025, 0.25, 30)
#: Level of the test the integral form must pass against the steady ones (``_candidates``).
INTEGRAL_ALPHA = 0.01
#: Load ratios Δm/m scanned by ``_resonance_shift``'s form ``load``.
LOAD_RATIOS = (-0.4, -0.3, -0.2, -0.1, 0.1, 0.2, 0.3, 0.45, 0.6, 0.8, 1.0, 1.5)
#: Its velocity-feedback corners a scanned, in units of the dominant mode's ω (0: none; the
#: friction's form ``loop`` scans the others).
LOAD_CORNERS = (0.0,) + tuple(float(v) for v in np.geomspace(0.05, 20.0, 9))
#: Level of the test the load form must pass against the one-parameter forms.
LOAD_ALPHA = 0.01


def _n_eff(r: np.ndarray) -> float:
    """Effective number of independent samples of a coloured residual: N / (1 + 2 Σ ρ_k), the
    sum over the initial positive sequence of its autocorrelation."""
    n = r.size
    if n < 4:
        return float(max(n, 1))
    x = r - r.mean()
    m = scipy.fft.next_fast_len(2 * n, real=True)   # ≥ 2n − 1: the linear autocorrelation
    f = np.fft.rfft(x, m)
    ac = np.fft.irfft(f * np.conj(f), m)[:n]
    if ac[0] <= 0:
        return float(n)
    rho = ac[1:min(n - 1, 2000)] / ac[0]
    stop = np.flatnonzero(rho <= 0)
    pos = rho[:stop[0]] if stop.size else rho
    s = float(np.cumsum(pos)[-1]) if pos.size else 0.0    # summed in order, as a loop would
    return float(max(n / (1.0 + 2.0 * s), 2.0))


# ---------------------------------------------------------------------------------------------
# the catalogue


def _refine(evaluate, grid, best_p, best_v, *, rounds=3, points=11):
    """Refine a scanned parameter around ``best_p`` (higher ``evaluate`` is better)."""
    grid = np.asarray(grid, float)
    i = int(np.argmin(np.abs(grid - best_p)))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    for _ in range(rounds):
        for p in np.linspace(lo, hi, points):
            v = evaluate(p)
            if v > best_v:
                best_p, best_v = p, v
        step = (hi - lo) / (points - 1)
        lo, hi = best_p - step, best_p + step
    return best_p, best_v


def _walk(evaluate, grid, walks=4):
    """``_scan`` of an evenly spaced ``grid`` about a first guess, following a best at its
    edge: the grid re-centred on that best and scanned again (at most ``walks`` times), then
    refined. (best parameter, best value, points tried)."""
    grid = np.asarray(grid, float)
    p, v, n_all = _scan(evaluate, grid, refine=False)
    for _ in range(walks - 1):
        i = int(np.argmin(np.abs(grid - p)))
        if 0 < i < grid.size - 1:
            break
        grid = grid + (p - grid[grid.size // 2])
        p, v, n = _scan(evaluate, grid, refine=False)
        n_all += n
    p, v = _refine(evaluate, grid, p, v)
    return p, v, n_all + 33


def _scan(evaluate, grid, refine=True, coarse=None, coarse_all=None):
    """(best parameter, best value, points tried) of ``evaluate`` over ``grid`` (then refined).
    ``coarse``: a cheap stand-in ranking the grid (the fit of the effect alone on what the model
    so far leaves); ``evaluate`` is then run on its best three points only. ``coarse_all``: the
    same stand-in over the whole grid at once (an array)."""
    grid = np.asarray(grid, float)
    if (coarse is not None or coarse_all is not None) and grid.size > 3:
        cv = (np.asarray(coarse_all(grid), float) if coarse_all is not None
              else np.array([coarse(p) for p in grid]))
        vals = {int(i): evaluate(grid[i]) for i in np.argsort(cv)[::-1][:3]}
        i = max(vals, key=vals.get)
        p, v = float(grid[i]), vals[i]
    else:
        vals = [evaluate(p) for p in grid]
        i = int(np.argmax(vals))
        p, v = float(grid[i]), vals[i]
    n = grid.size
    if refine and grid.size > 1:
        p, v = _refine(evaluate, grid, p, v)
        n += 33
    return p, v, n


def sincos_rss(r, u, freqs) -> np.ndarray:
    """Residual sum of squares of ``r`` after the least-squares fit of [sin, cos](2π·f·u), for
    every f of ``freqs`` (u and r of one length), in closed form and in blocks of frequencies
    (a 2 × 2 normal equation each; a singular one, f·u all on the sine's zeros, explains 0)."""
    r, u = np.asarray(r, float), np.asarray(u, float)
    rr = float(r @ r)
    freqs = np.asarray(freqs, float)
    out = np.empty(freqs.size)
    blk = max(1, min(64, 2_000_000 // max(u.size, 1)))  # ≤ 16 MB a block matrix
    for i0 in range(0, freqs.size, blk):
        P = (2 * np.pi * freqs[i0:i0 + blk, None]) * u[None, :]
        Sn, Cs = np.sin(P), np.cos(P)
        a, b = Sn @ r, Cs @ r
        ss, cc, sc = (Sn * Sn).sum(1), (Cs * Cs).sum(1), (Sn * Cs).sum(1)
        det = ss * cc - sc * sc
        ok = det > 1e-12 * np.maximum(ss * cc, 1e-300)
        expl = np.where(ok, (cc * a * a - 2 * sc * a * b + ss * b * b)
                        / np.where(ok, det, 1.0), 0.0)
        out[i0:i0 + blk] = rr - expl
    return out


def undo_response(r, h, eps: float = 0.01) -> np.ndarray:
    """``r`` with the response ``h`` taken back out: the regularised inverse
    H*/(|H|² + eps·max|H|²) applied by FFT, zero-padded to the two lengths (what wraps
    around is the inverse's decayed tail). For ranking candidates only: where |H| is small
    the gain stays below 1/(2·√(eps·max|H|²)) instead of amplifying noise."""
    r, h = np.asarray(r, float), np.asarray(h, float)
    n = 1 << int(np.ceil(np.log2(max(r.size + h.size, 2))))
    H = np.fft.rfft(h, n)
    a2 = np.abs(H) ** 2
    inv = np.conj(H) / (a2 + eps * float(a2.max()))
    return np.fft.irfft(np.fft.rfft(r, n) * inv, n)[:r.size]


class _Scorer:
    """How a candidate regressor or prediction scores on axis A against ``base`` (the model so
    far): the fit part's residual sum of squares, negated (higher is better).

    Parameters are scanned against the twin's mean physics (no draw): the draw could trade
    part of an effect for a machine inside the spread and bias its size toward none; the draw
    enters the test (diagnose_arrays), which decides whether the effect is there. The
    ``quick_*`` scores are least squares on the base's residual alone, for coarse scans. A
    fan's frequency is scored against what the draw leaves (``score_draw``, _periodic_time,
    _switched_on): there the draw takes out a mode's ring that pulls it, not the fan."""

    def __init__(self, A: _Axis, base: _Model, named=None):
        self.A, self.base = A, base
        self.named = named or {}
        self.cmd, self.ts, self.fit = A.cmd, A.ts, A.fit
        self.pred, self.extra = base.pred, base.extra
        # an effect inside the machine passes through its dynamics: the twin's mean response,
        # the one the extended profile applies (twin.extensions)
        self.hd = A.phys.mean
        self.rfit = base.resid_mean[A.fit]
        # a model that fitted the twin's lag error (a backlash on a servo) keeps fitting it
        self.lag = base.lag_s is not None

    def with_extra(self, G) -> _Model:
        return self.A.fit_model(self.pred, np.hstack([self.extra, G]), self.lag)

    def score_extra(self, G) -> float:
        e = self.with_extra(G).resid_mean[self.fit]
        return -float(e @ e)

    def score_draw(self, G) -> float:
        """``score_extra`` on what the plant draw leaves (the draw fitted with G)."""
        e = self.with_extra(G).resid[self.fit]
        return -float(e @ e)

    def score_pred(self, p, G=None, lag=False) -> float:
        m = self.A.fit_model(p, self.extra if G is None else np.hstack([self.extra, G]),
                             lag or self.lag)
        e = m.resid_mean[self.fit]
        return -float(e @ e)

    def quick_extra(self, G) -> float:
        Gf = G[self.fit]
        w = np.linalg.lstsq(Gf, self.rfit, rcond=None)[0]
        e = self.rfit - Gf @ w
        return -float(e @ e)

    def quick_sincos(self, u, freqs, resid=None) -> np.ndarray:
        """``quick_extra`` of G = [sin, cos](2π·f·u) for every f of ``freqs`` at once (u on
        the log's rows). ``resid``: the fit part's residual to explain (default the twin
        mean's, ``rfit``)."""
        r = self.rfit if resid is None else resid
        return -sincos_rss(r, np.asarray(u, float)[self.fit], freqs)

    def quick_pred(self, p, lag=False) -> float:
        e = self.rfit - (p - self.pred)[self.fit]
        if (lag or self.lag) and self.A.lag.shape[1]:
            L = self.A.lag[self.fit]
            e = e - L @ np.linalg.lstsq(L, e, rcond=None)[0]
        return -float(e @ e)


#: Kinds an axis may carry more than once (two fans; a belt's tooth pitch and its pulley's
#: runout), each again at a frequency / wavelength the named ones' cannot be told from
#: (``_apart``).
REPEATABLE = ("periodic_time", "periodic_position")


def _candidates(A: _Axis, base: _Model, named_kinds, other: _Axis, base_other: _Model):
    """[(kind, form, params, model, n_tried, q)] of every catalogue kind on axis A (delay,
    gain and resonance_shift once per axis), each parameter scanned on the fit part against
    ``base`` (the model so far). ``named_kinds``: kind -> the parameters of those named on
    this axis."""
    S = _Scorer(A, base, named_kinds)
    out = [c for c in (_periodic_time(S), _periodic_position(S), _backlash(S), _friction(S))
           if c is not None]
    if "delay" not in named_kinds:
        out.append(_delay(S))
    if "gain" not in named_kinds:
        out.append(_gain(S))
    if "resonance_shift" not in named_kinds:
        out.append(_resonance_shift(S))
    out.append(_cross_coupling(S, other))
    return out


#: How many of periodic_time's peaks (three of the mean's residual, three of the draw's) are
#: scanned with the model once the closed form has ranked them.
SCANNED_PEAKS = 2


def _periodic_time(S: _Scorer):
    """A sinusoid in time, from the three largest spectral peaks of the fit-part residual of
    the twin's mean, and the three largest of what the plant draw leaves (others).

    Each peak's frequency is scanned on what the plant draw leaves (``_Scorer.score_draw``),
    and among the peaks the one whose sinusoid explains most of it is taken, the draw being
    what the test asks an effect to beat. Against the twin's mean (as every other parameter
    is scanned) the ring of a mode the twin places a little off pulls a fan near it: a new
    belt machine's fan at 34.9 Hz, 1.3 Hz above y's mode (tests/foreign seed 804), came out at
    34.83 Hz, and 0.07 Hz lost the phase over the held-out part (7.3 µm left of 13.2 with the
    draw; at 34.885 Hz 2.4 µm); on the 390 logs of the regression sweep nine fans' frequencies
    moved by 0.01–0.03 Hz, eight of them toward the truth. The largest peak of
    the mean's residual is often a lightly damped mode the twin places a little off, which the
    draw and the mode's ring (``diagnose._ring_bar``) explain: a foreign belt machine (seed 343,
    x at 34.6 Hz ζ 0.03, members at 33.8–35.5 Hz) had its 11.7 µm fan at 24.5 Hz (the second
    peak) passed over for a 34.3 Hz sinusoid the test then refused."""
    ts, fit = S.ts, S.fit
    t = np.arange(S.cmd.size) * ts
    nf = S.base.resid_mean[fit].size
    n_fft = 1 << int(np.ceil(np.log2(max(nf, 2) * 4)))
    f = np.fft.rfftfreq(n_fft, ts)
    band = (f >= 1.0) & (f <= 0.45 / ts)
    df = f[1] - f[0]
    # a second fan must lie apart from those named: two sinusoids closer than 2/T over the fit
    # part's T are one whose amplitude or phase drifts
    sep = 2.0 / (nf * ts)
    named = [p["frequency_hz"] for p in S.named.get("periodic_time", ())]
    taken = ~_apart(f, named, sep)
    peaks = []
    # the peaks of the mean's residual, then of what the draw leaves: where the twin's mean
    # misses a slow pole by far more than a fan's size (seed 334 of tests/foreign: 161 µm
    # RMS at 3 Hz on x, the draw absorbing all but 6.6 µm), the mean's three peaks all lie
    # on that miss and a 9.2 µm fan at 30 Hz was never scanned
    for rf in (S.base.resid_mean[fit], S.base.resid[fit]):
        R = np.abs(np.fft.rfft((rf - rf.mean()) * np.hanning(nf), n_fft))
        Rb = np.where(band & ~taken, R, 0.0)
        for _ in range(3):
            i = int(np.argmax(Rb))
            if Rb[i] <= 0:
                break
            peaks.append(f[i])
            Rb[max(i - 8, 0):i + 9] = 0.0
            taken[max(i - 8, 0):i + 9] = True

    def sincos_t(fr):
        return np.column_stack([np.sin(2 * np.pi * fr * t), np.cos(2 * np.pi * fr * t)])

    # each peak's grid scored in closed form against what the draw leaves (the measure the
    # choice below makes), and only the two best peaks scanned with the model: six full scans
    # cost ~250 model fits a diagnosis, two cost 84, and the closed form ranks as they do
    grids = [np.linspace(f0 - 2 * df, f0 + 2 * df, 9) for f0 in peaks]
    tried = 9 * len(grids)
    if len(grids) > SCANNED_PEAKS:
        q = S.quick_sincos(t, np.concatenate(grids), resid=S.base.resid[fit])
        q = q.reshape(len(grids), 9)
        grids = [grids[i] for i in np.argsort(q.max(axis=1))[::-1][:SCANNED_PEAKS]]
    best = None
    for grid in grids:
        fr, _, n = _scan(lambda fr: S.score_draw(sincos_t(fr)), grid)
        tried += n - grid.size
        m = S.with_extra(sincos_t(fr))
        v = -float(np.sum(m.resid[fit] ** 2))
        if best is None or v > best[1]:
            best = (fr, v, m)
    if best is None:
        return None
    fr, _, m = best
    if not _apart(fr, named, sep):
        return None
    form, extra = "time", {}
    on = _switched_on(S, t, sincos_t, fr, df, m)
    if on is not None and _apart(on[0], named, sep):
        fr, t_on, m, n_on = on
        tried += n_on
        form, extra = "switched_on", {"switched_on_s": float(t_on)}
    w = m.w_mean[-2:]
    return ("periodic_time", form, {"frequency_hz": float(fr),
                                    "amplitude_mm": float(np.hypot(*w)),
                                    "phase_rad": float(np.arctan2(w[1], w[0])), **extra},
            m, tried, 3)


def _apart(v, named, sep):
    """Whether ``v`` (a value or an array) lies at least ``sep`` from every value of ``named``."""
    v = np.asarray(v, float)
    if not len(named):
        return np.ones(v.shape, bool) if v.ndim else True
    d = np.min(np.abs(v[..., None] - np.asarray(named, float)), axis=-1)
    return d >= sep


#: Level of the test a fan switched on during the log must pass against one running throughout.
SWITCH_ALPHA = 0.01


def _switched_on(S: _Scorer, t, sincos_t, fr, df, m_st):
    """A fan switched on during the fit part (the sinusoid from t_on on) where that fits the
    fit part better than the fan running throughout, beyond χ²₁ at SWITCH_ALPHA
    Bonferroni-divided over the onsets and frequencies tried (the statistic of diagnose's
    fit-part test, with the plant draw): (frequency, t_on, model, tried) or None.

    Onsets are scanned from the fit part's first tenth on: the first samples carry the
    turn-on transient of a fan the simulation starts with the log (foreign 621 and 625:
    "on at 0.05 s"), and an onset that early leaves the fit part's fan as it was. A fan
    switched off (or changing speed) during the fit part is not this form: the held-out part,
    which must confirm every effect, no longer has it."""
    fit = S.fit
    t0, t1 = t[fit.start], t[fit.stop - 1]
    onsets = np.linspace(t0 + 0.1 * (t1 - t0), t1, 42)[:-1]

    def gated(f, t_on):
        return sincos_t(f) * (t >= t_on)[:, None]

    # the onset at the sinusoid's frequency, the frequency from that onset on, the onset
    # again. A peak of the whole fit part is coarse where the fan ran for part of it, and
    # beside a lightly damped mode it leans toward the mode's ring (the twin's mode a little
    # off the plant's) by more than the ±2 bins about it: seed 722 of tests/foreign, a fan at
    # 21.5 Hz 2.9 Hz below y's mode (ζ 0.023), its peak at 22.09 Hz; the grid's edge, 21.84
    # Hz, lost the phase over the held-out part and nothing was named. The grid follows a
    # best at its edge, and the frequency is scored on what the plant draw leaves, which
    # takes that ring out (against the mean: 21.64 Hz; against the draw: 21.59 Hz)
    t_on, _, n1 = _scan(lambda v: S.score_extra(gated(fr, v)), onsets, refine=False,
                        coarse=lambda v: S.quick_extra(gated(fr, v)))
    fr, _, n2 = _walk(lambda f: S.score_draw(gated(f, t_on)),
                      np.linspace(fr - 2 * df, fr + 2 * df, 9))
    t_on, _, n3 = _scan(lambda v: S.score_extra(gated(fr, v)), onsets,
                        coarse=lambda v: S.quick_extra(gated(fr, v)))
    n = n1 + n2 + n3
    m_on = S.with_extra(gated(fr, t_on))
    e1, e0 = m_on.resid[fit], m_st.resid[fit]
    ss1 = float(e1 @ e1)
    tstat = (float(e0 @ e0) - ss1) / max(ss1 / _n_eff(e1), 1e-30)
    if tstat <= float(stats.chi2.isf(SWITCH_ALPHA / n, 1)):
        return None
    return fr, t_on, m_on, n


#: The shortest periodic_position wavelength scanned, mm: a stepper's electrical cycle on a
#: 16-tooth GT2 pulley (32 mm / 50) halved — its second harmonic, 0.32 mm.
LAMBDA_MIN_MM = 0.3


def _periodic_position(S: _Scorer):
    """A sinusoid of the commanded position, at the output or through the dynamics."""
    cmd, hd = S.cmd, S.hd

    def sincos_x(lam):
        return np.column_stack([np.sin(2 * np.pi * cmd / lam), np.cos(2 * np.pi * cmd / lam)])

    def sincos_x_dyn(lam):
        G = sincos_x(lam)
        return np.column_stack([respond(G[:, 0], hd), respond(G[:, 1], hd)])

    # 1–60 mm on a geometric grid; below 1 mm (a stepper's electrical cycle, 4 full steps:
    # 0.8 mm on a 20-tooth GT2 pulley, and its harmonic 0.4 mm) a sinusoid stays in phase over
    # the axis's range R only within Δλ/λ ≈ λ/(8R): there a uniform grid of wavenumbers,
    # 1/(4R) apart. One scan over both: the coarse fit ranks them together.
    dk = 1.0 / (4.0 * max(float(np.ptp(cmd[S.fit])), 1.0))
    # a second one apart from those named by 2/R in wavenumber over the range R the fit part
    # covers (as fans by 2/T in frequency)
    named = [1.0 / p["wavelength_mm"] for p in S.named.get("periodic_position", ())]

    def keep(lams):
        lams = np.asarray(lams, float)
        return lams[_apart(1.0 / lams, named, 8.0 * dk)]

    fine = 1.0 / np.arange(1.0 + dk, 1.0 / LAMBDA_MIN_MM + 0.5 * dk, dk)
    grid = keep(np.sort(np.concatenate([fine, np.geomspace(1.0, 60.0, 300)])))
    lam, v_out, n = _scan(lambda l: S.score_extra(sincos_x(l)), grid,
                          coarse_all=lambda ls: S.quick_sincos(cmd, 1.0 / ls))
    if lam < 1.0:
        dgrid = np.sort(1.0 / np.linspace(1.0 / lam - 20 * dk, 1.0 / lam + 20 * dk, 41))
    else:
        dgrid = np.geomspace(lam / 1.1, lam * 1.1, 41)
    dgrid = keep(dgrid)
    if not dgrid.size:
        dgrid = np.array([lam])
    lam_d, v_dyn, n2 = _scan(lambda l: S.score_extra(sincos_x_dyn(l)), dgrid,
                              coarse=lambda l: S.quick_extra(sincos_x_dyn(l)))
    # the dynamics form ranks the 1–60 mm grid on its own too: an error through a servo's
    # loop is filtered and lagged unevenly across the speeds of a print, so the output form's
    # best can lie far from it (foreign servo 606: 4.2 mm, 11.9 µm, where the output form
    # ranked 66 mm first). Ranked in closed form on what the twin leaves with its mean
    # response taken back out (undo_response); not below 1 mm, whose v/λ of hundreds of Hz
    # lies far above any loop, where the inverse only amplifies noise.
    undone = undo_response(S.rfit, hd)
    lam_g, v_g, n3 = _scan(lambda l: S.score_extra(sincos_x_dyn(l)),
                           keep(np.geomspace(1.0, 60.0, 300)),
                           coarse_all=lambda ls: -sincos_rss(undone, cmd[S.fit], 1.0 / ls))
    if v_g > v_dyn:
        lam_d, v_dyn = lam_g, v_g
    n2 += n3
    if v_dyn >= v_out:
        form, G, lam = "dynamics", sincos_x_dyn(lam_d), lam_d
    else:
        form, G = "output", sincos_x(lam)
    if not _apart(1.0 / lam, named, 8.0 * dk):
        return None
    m = S.with_extra(G)
    w = m.w_mean[-2:]
    return ("periodic_position", form, {"wavelength_mm": float(lam),
                                        "amplitude_mm": float(np.hypot(*w)),
                                        "phase_rad": float(np.arctan2(w[1], w[0])),
                                        "form": form},
            m, n + n2, 3)


def _backlash(S: _Scorer):
    """A play of width b (unit weight: the width is the parameter) + a free offset.

    On an axis with integral action the twin's lag error is fitted with it (``lag_s``, with
    its prior: diagnose._lag_column): on steady motion a lag τ·v and the play's b/2·sign(v)
    are nearly one regressor, and without it the width took the lag error in (tests/foreign
    servo_screw: −58 … +32 %)."""
    A, cmd, pred = S.A, S.cmd, S.pred
    ones = np.ones((cmd.size, 1))

    def bl_input(b):
        return pred + respond(fx.play(cmd, b), A.phys.mean) - A.p0

    def bl_output(b):
        return pred + fx.play(A.p0, b) - A.p0

    grid = np.geomspace(0.005, 0.5, 30)
    best = None
    tried = 0
    for form, make in (("input", bl_input), ("output", bl_output)):
        b, v, n = _scan(lambda b: S.score_pred(make(b), ones, lag=True), grid,
                        coarse=lambda b: S.quick_pred(make(b), lag=True))
        tried += n
        if best is None or v > best[2]:
            best = (form, b, v, make)
    form, b, _, make = best
    m = A.fit_model(make(b), np.hstack([S.extra, ones]), lag=True)
    params = {"magnitude_mm": float(b), "offset_mm": float(m.w_mean[-1]), "form": form}
    if m.lag_s is not None:
        params["lag_s"] = m.lag_s
    return ("backlash", form, params, m, tried, 2)


def _friction(S: _Scorer):
    """A Coulomb force; free weight = the quasi-static lag.

    A Coulomb force opposes the motion: it dissipates, so the axis lags (weight > 0). A lead
    is not friction: on a PID servo whose modal fit leaves a few µm of lead (tests/foreign,
    seed 5) "friction −0.010 mm" was named on two of three clean logs, and an integrator's
    transients at reversals came out as −0.003 to −0.033 mm (benchmarks/foreign_effects.py).
    Only forms with a lag compete: a lag against the twin's mean (what is reported) and with
    the plant draw (what the test judges). A belt machine's fan log (tests/foreign seed 805,
    a machine never used before) had "friction x 0.00015 mm" named beside its fan: a lag of
    0.15 µm against the mean, a lead of 1.55 µm with the draw, 23 % of the held-out part.

    The same force as a loop with integral action (a servo) sees it: washed out in τ_i
    (twin.extensions.integral_sign). Tried on every axis: a servo's integrator often leaves
    no real pole in the modal fit (AxisPhysics.integral_action), its pole below the FRF band
    or two heavily damped pairs in its place — tests/foreign 901 (x: 16.1 Hz ζ 0.84, 18.7 Hz
    ζ 0.82), 902 (y: measured from 5 Hz), 607: their frictions were sized 77.0, 77.7 and
    72.7 % low in a steady form, held out 13.7 → 12.9, 4.7 → 4.2 µm; washed out, 4.9 and
    2.2 µm. (Gated on real poles once, when a corexy's friction, seed 18, took this form and
    came out a tie with backlash; the bar below keeps it off there.) It nests the steady
    forms (τ_i → ∞) and has τ_i to spare, so it must also beat
    the best of them significantly: its gain in the fit part's squares, in units of its
    residual variance per effective sample, above the χ²(1) quantile at 1 %
    Bonferroni-divided over the τ_i tried. A best τ_i at the lowest end of its scan (5 ms,
    quicker than the loop's own response: a PID's K_p/K_i is 4–10 loop time constants) is not
    resolved, as a delay at the lowest end of its scan is not: the data want a pulse at every
    reversal, not a force the loop washes out. On a servo's clean log (tests/foreign, seed 17)
    it took 2.20 → 1.94 µm of the y residual the plant draw leaves as "friction 0.027 mm,
    τ_i 5 ms" (on one CPU's last bits, not another's); the true frictions of the foreign
    servos wash out in 11–80 ms.

    Form ``loop``: the force through the loop that holds the load, (1 − H)/(s (s + a)) from
    the modal model (``ModalModel.load_force``, the corner a scanned as the load resonance
    shift's, ``corner_hz``; the magnitude the peak of its step response): for a PID servo
    with its derivative on the measurement it is exact, the loop's dynamics on the way,
    which the integral form's washout through the force response only approximates
    (tests/foreign 900 x: −70.6 % in a steady form, −8.5 % through the loop, held out 16.6 →
    4.3 µm). Tried on a loop only (a dominant mode that does not ring, as the load form):
    on a belt + hotend (tests/foreign 708) it took the carriage's sticking friction. It
    faces the same bar as the integral form (τ and corners counted together);
    each washed-out form is tested on its own residual and the best of those passing taken.

    The bar is judged twice, each at half the level: on what the twin's mean leaves and, where
    the best steady form has a free weight, on what the plant draw leaves (the test that
    finally judges every effect, diagnose._choose). Where the twin's mean misses the axis by
    far more than the force (tests/foreign 905 x, 26 µm held out; 906 x, 17 x) its residual
    keeps 5–7 effective samples and no washed-out form passed against the mean: 905 and 906
    were sized 55 and 54 % low in a steady form, 17 59 %; with the draw fitted beside them the
    loop form passes (draw statistic 907 against a bar of 13.5 on 905) and they come out +5.0,
    −5.3 and −28.7 % (held out 25.0 → 20.2, 7.7 → 5.3 µm, 17's the same), 16's integral form
    −10.4 → +8.4 % (66.8 → 57.4 µm); no other of 486 logs changed. A ``stick`` best is not
    compared with the draw: its unit weight leaves the draw what a free one would take, and
    every washed-out form then "passes" by thousands on clean logs.

    A Coulomb force of the carriage's *own* velocity (benchA's) makes it stick at a reversal
    until the drive's pull exceeds the force: quasi-statically, a play of total width
    2·magnitude on the response (form ``stick``, the magnitude scanned as a backlash's width,
    unit weight). A backlash on the response (its form ``output``, with a free offset) is the
    same model: where the held-out part cannot tell them apart the backlash is named and
    the friction stated as its tie (diagnose._choose). On the
    foreign belt machines' such frictions (benchmarks/foreign_variants.py) the steady forms
    sized them 14 % low or missed them; benchA's friction keeps its ``force`` form."""
    A, cmd, ts, fit, hd = S.A, S.cmd, S.ts, S.fit, S.hd
    best = None
    for tau in FRICTION_TAU_S:
        s = relax_sign(cmd, ts, tau)
        forms = [("output", s[:, None]), ("response", respond(s, hd)[:, None])]
        if A.phys.force is not None:
            forms.append(("force", respond(s, A.phys.force)[:, None]))
        for form, G in forms:
            m = S.with_extra(G)
            if not (m.w_mean[-1] > 0 and m.theta[-1] > 0):
                continue
            e = m.resid_mean[fit]
            v = -float(e @ e)
            # τ is seen only where the axis rests after moving: the simplest (first) wins ties
            if best is None or v > best[0] + 1e-9 * abs(best[0]):
                best = (v, form, tau, m)

    def stuck(mag):
        return S.pred + fx.play(A.p0, 2.0 * mag) - A.p0

    mag, v, n_stick = _scan(lambda mag: S.score_pred(stuck(mag)), STICK_MM,
                            coarse=lambda mag: S.quick_pred(stuck(mag)))
    if best is None or v > best[0]:
        best = (v, "stick", mag, A.fit_model(stuck(mag), S.extra, S.lag))
    def best_lag(form, columns):
        """(score, form, parameter, model) of the best of (parameter, column) fitted as a
        lag against the mean and with the draw, or None."""
        out = None
        for par, G in columns:
            m = S.with_extra(G[:, None])
            if not (m.w_mean[-1] > 0 and m.theta[-1] > 0):
                continue
            e = m.resid_mean[fit]
            v = -float(e @ e)
            if out is None or v > out[0]:
                out = (v, form, par, m)
        return out

    fh = A.phys.force if A.phys.force is not None else hd
    taus_i = INTEGRAL_TAU_S
    best_int = best_lag("integral", ((t, respond(integral_sign(cmd, ts, t), fh)) for t in taus_i))
    if best_int is not None and best_int[2] <= taus_i[0]:
        best_int = None  # unresolved: the lowest end of the scan
    corners = _loop_corners(A)
    s0 = relax_sign(cmd, ts, 0.0)
    best_loop = best_lag("loop", ((a, respond(s0, hf)) for a, hf in
                                  ((a, A.phys.load_force(a)) for a in corners) if hf is not None))
    # a washed-out form must beat the steady ones significantly (against the mean, or with the
    # draw: each at half the level); of those that do, the best
    bar = stats.chi2.ppf(1.0 - INTEGRAL_ALPHA / (2 * (len(taus_i) + len(corners))), 1)
    washed = []
    for c in (best_int, best_loop):
        if c is None:
            continue
        e = c[3].resid_mean[fit]
        if best is None or (c[0] - best[0]) * _n_eff(e) / float(e @ e) > bar or (
                best[1] != "stick" and _beats_with_draw(c[3], best[3], fit, bar)):
            washed.append(c)
    if washed:
        best = max(washed, key=lambda c: c[0])
    if best is None:
        return None
    _, form, tau, m = best
    tried = 3 * len(FRICTION_TAU_S) + len(taus_i) + len(corners) + n_stick
    if form == "stick":
        return ("friction", form, {"magnitude_mm": float(tau), "form": form}, m, tried, 2)
    if form == "loop":
        return ("friction", form, {"magnitude_mm": float(m.w_mean[-1]),
                                   "corner_hz": float(tau / (2 * np.pi)), "form": form},
                m, tried, 2)
    key = "integral_s" if form == "integral" else "relax_s"
    return ("friction", form, {"magnitude_mm": float(m.w_mean[-1]), key: float(tau),
                               "form": form}, m, tried, 2)


def _beats_with_draw(m, m0, fit, bar: float) -> bool:
    """Whether model m leaves less than m0 of the fit part once the plant draw is fitted
    beside each, by more than ``bar`` (a χ²(1) quantile): the gain in squares in units of m's
    residual variance per effective sample."""
    e, e0 = m.resid[fit], m0.resid[fit]
    ss = float(e @ e)
    return (float(e0 @ e0) - ss) * _n_eff(e) / max(ss, 1e-300) > bar


def _delay(S: _Scorer):
    """The prediction delayed (unit weight: the delay is the parameter).

    A best delay at or below the scan's smallest, 0.2 ms (a tenth of a 2 ms sample), is not
    resolved: the data want less delay than the scan tells from none, which is the twin's own
    phase error, not a dead time. Such a candidate is the model without a delay (it explains
    nothing and never passes; its points still count in the round's Bonferroni divisor). On
    foreign servos a 0.2 ms "delay" was named beside a resonance shift (tests/foreign seed 25)
    and beside a friction (seed 17)."""
    pred, ts = S.pred, S.ts
    grid = np.geomspace(2e-4, 0.05, 40)
    d, v, n = _scan(lambda d: S.score_pred(fx.delay_signal(pred, d, ts)), grid,
                    coarse=lambda d: S.quick_pred(fx.delay_signal(pred, d, ts)))
    if d <= grid[0]:
        d = 0.0
    m = S.A.fit_model(fx.delay_signal(pred, d, ts), S.extra, S.lag)
    return ("delay", "command", {"seconds": float(d)}, m, n, 1)


def _gain(S: _Scorer):
    """A gain about the machine origin: a free weight on the prediction."""
    m = S.with_extra(S.pred[:, None])
    return ("gain", "command", {"scale": float(1.0 + m.w_mean[-1])}, m, 1, 1)


def _resonance_shift(S: _Scorer):
    """The dominant mode moved (unit weight: its frequency is the parameter). The rescaled
    form's frequency is the peak of |H| (as the virtual machine moves it); the mass form's the
    dominant mode's natural frequency (as benchA's labels state it).

    Form ``load``: the load of the whole loop heavier by a ratio, seen through a velocity
    feedback with corner a (``ModalModel.loaded``, both scanned), reported as the pole pair
    at the loaded response's peak (``ModalModel.pair_at_peak_hz``), with ``load_ratio`` and
    ``corner_hz``. A PID servo's table 25–40 % heavier (tests/foreign: seeds 900, 901, 905,
    906, 16, 19, 25, loops at ζ 0.74–0.97) moves the loop's poles and damping together,
    which moving one mode cannot follow: those shifts were missed. It has a second
    parameter, so it is taken only where it beats the best one-parameter form significantly
    (its gain in the fit part's squares, in units of its residual variance per effective
    sample, above the χ²(1) quantile at LOAD_ALPHA Bonferroni-divided over the corners
    tried), and then tested with q = 2.

    A best move whose response stays inside the measured members' spread at every measured
    frequency (``AxisPhysics.move_inside_spread``) is a machine of the profile's own
    population, not a change of it: such a candidate is the model without the move (it
    explains nothing and never passes; its points still count in the round's Bonferroni
    divisor), as for a delay at the lowest end of its scan."""
    A, cmd, ts, pred = S.A, S.cmd, S.ts, S.pred
    f_mode = A.phys.mode_hz
    f_peak = fx.dominant_mode_hz(A.phys.mean, ts)
    forms = [("scale", lambda f1: fx.rescale_impulse_response(A.phys.mean, f1 / f_peak))]
    if A.phys.shifted is not None:
        forms.insert(0, ("mass", A.phys.shifted))
    grid = f_mode * np.linspace(0.6, 1.5, 19)
    best = None
    tried = 0
    for form, hfun in forms:
        def p_of(f1, hfun=hfun):
            return pred + respond(cmd, hfun(f1)) - A.p0
        f1, v, n = _scan(lambda f1: S.score_pred(p_of(f1)), grid,
                         coarse=lambda f1: S.quick_pred(p_of(f1)))
        tried += n
        if best is None or v > best[2]:
            best = (form, f1, v, p_of)
    form, f1, _, p_of = best
    f_nominal = f_mode if form == "mass" else f_peak
    if A.phys.move_inside_spread(form, f1, f_peak):
        f1 = f_nominal
    m = A.fit_model(p_of(f1), S.extra, S.lag)
    out = ("resonance_shift", form, {"frequency_hz": float(f1), "form": form}, m, tried, 1)
    load, n_load = _loaded(S, best[2])
    if load is None:
        return out[:4] + (tried + n_load, 1)
    ratio, a = load
    tried += n_load
    m_l = A.fit_model(pred + respond(cmd, A.phys.loaded(ratio, a)) - A.p0, S.extra, S.lag)
    params = {"frequency_hz": float(A.phys.loaded_hz(ratio, a)), "load_ratio": float(ratio),
              "corner_hz": float(a / (2 * np.pi)), "form": "load"}
    if A.phys.move_inside_spread("load", 0.0, f_peak, load=(ratio, a)):
        params["frequency_hz"], m_l = float(f_mode), A.fit_model(pred, S.extra, S.lag)
    return ("resonance_shift", "load", params, m_l, tried, 2)


def _loop_corners(A: _Axis) -> list:
    """The velocity-feedback corners a (rad/s, LOAD_CORNERS above 0 times the dominant mode's
    ω) the loop forms scan on axis A, or [] where A is no loop: its dominant mode rings (ζ <
    RINGING_ZETA, a belt's) or there is no modal physics (``_loaded``'s docstring says why)."""
    zeta = A.phys.mode_zeta
    if A.phys.load_force is None or zeta is None or zeta < RINGING_ZETA:
        return []
    return [c * 2 * np.pi * A.phys.mode_hz for c in LOAD_CORNERS if c > 0]


def _loaded(S: _Scorer, v_best: float):
    """``_resonance_shift``'s form ``load`` where it beats ``v_best`` (the one-parameter
    forms' best fit-part score) significantly: ((ratio, a rad/s) or None, points tried).

    Tried where the dominant mode does not ring (ζ ≥ RINGING_ZETA: a closed loop); a lightly
    damped mode's load is the ``mass`` form (one mass on a belt: the load form with a = 0).
    Tried on every axis, it took what a named delay left on benchA's belts (logs 04 and 12)
    and a belt + hotend's (tests/foreign seed 370) as a small load behind a corner 20 times
    the mode: a resonance shift beside the delay. (At a → ∞ the form fades to r·s/a·(1 − H),
    a phase lead or lag. A best corner at the top of the scan is no sign of that on a loop:
    901 x's real shift, fitted as two pairs at 16.1 / 18.7 Hz, is best there too.)"""
    A, cmd, pred = S.A, S.cmd, S.pred
    loop = _loop_corners(A)
    if A.phys.loaded is None or not loop:
        return None, 0
    corners = [0.0] + loop
    n = len(LOAD_RATIOS) * len(corners) + 2 * 18

    def p_of(ratio, a):
        h = A.phys.loaded(ratio, a)
        return None if h is None else pred + respond(cmd, h) - A.p0

    def score(ratio, a, quick=False):
        p = p_of(ratio, a)
        if p is None:
            return -np.inf
        return S.quick_pred(p) if quick else S.score_pred(p)

    coarse = sorted(((score(r, a, quick=True), r, a) for r in LOAD_RATIOS for a in corners),
                    reverse=True)
    top = [(score(r, a), r, a) for _, r, a in coarse[:3] if np.isfinite(_)]
    if not top:
        return None, n
    v, ratio, a = max(top)
    # refined coordinate by coordinate: the ratio between its grid neighbours, the corner
    # between its geometric ones (a = 0 stays: no velocity feedback)
    rs = np.asarray(LOAD_RATIOS)
    for _ in range(2):
        i = int(np.argmin(np.abs(rs - ratio)))
        lo, hi = rs[max(i - 1, 0)], rs[min(i + 1, rs.size - 1)]
        for r in np.linspace(lo, hi, 9):
            sv = score(r, a)
            if sv > v:
                v, ratio = sv, float(r)
        if a > 0:
            for c in a * np.geomspace(0.5, 2.0, 9):
                sv = score(ratio, c)
                if sv > v:
                    v, a = sv, float(c)
    m = A.fit_model(p_of(ratio, a), S.extra, S.lag)
    e = m.resid_mean[S.fit]
    bar = stats.chi2.ppf(1.0 - LOAD_ALPHA / len(corners), 1)
    if (v - v_best) * _n_eff(e) / float(e @ e) <= bar:
        return None, n
    return (ratio, a), n


def _cross_coupling(S: _Scorer, other: _Axis):
    """The other axis's motion: its predicted acceleration (its carriage's reaction, ringing
    included), its commanded one (a motor force that follows the command, tests/foreign
    cross_coupling_cmd), the predicted one twice through the dynamics (a corexy's belts) or
    its position; where the modal fit shows the antiresonance of the frame the motor rides
    on, the predicted and the commanded one through the axis's response to a force on that
    frame (``twin.physics.frame_model``: forms ``frame``, ``frame_command``); the form
    that fits best.

    The frame forms: the other carriage's reaction pushes the frame, which reaches the nozzle
    along the whole chain (frame, belt, carriage, hotend) without the command path's
    antiresonance, so it rings more near the modes than the command's response: on the
    belt + hotend machines of tests/foreign (seeds 800–806) the command-path forms sized it
    +5 … +63 % high (625 y at 30 Hz: |H_frame| 6.37 against |H_cmd| 5.14).

    The form is chosen, and its weight fitted, jointly with the plant draw (``score_draw``,
    ``theta``), not against the twin's mean alone as every other kind's: the other axis's
    motion through this axis's modes is much like this axis's own motion through a stiffer
    or softer machine, so against the mean it takes up the mean's own miss. benchA's frame
    force (3e-6, its frame at 100 Hz behind a 36 Hz mode) came out −0.3 % through the command
    path against the mean — two errors cancelling: through the frame −12.8 % against the
    mean, +2.0 % with the draw; tests/foreign 805: +60.6 % → +40 % → +2.5 %. Chosen against
    the mean, the form that best fitted the mean's miss won where the draw explains much (907
    y, 802 x: the ``belt`` form, weight ~0, and the commanded coupling was missed).

    On a loop (a dominant mode that does not ring: a servo) also the predicted and the
    commanded acceleration through the force path of the load the loop holds, (1 − H)/(s (s +
    a)) (``ModalModel.load_force``, forms ``loop``, ``loop_command``, the corner a scanned
    as the friction's, ``corner_hz``): a servo's table pushed by the other axis reaches the
    sensor through its PID loop, which no command-path form carries — tests/foreign 900's and
    905's couplings were sized 16–54 % low in those, 11–19 % through the loop, each with
    its true source."""
    ts, hd = S.ts, S.hd
    po = other.p0

    def acc(p):
        return np.gradient(np.gradient(p, ts), ts)

    a = acc(po)
    G_acc = respond(a, hd)[:, None]
    forms = {"acceleration": G_acc, "command": respond(other.cmd_acc, hd)[:, None],
             "belt": respond(G_acc[:, 0], hd)[:, None], "position": (po - po[0])[:, None]}
    fh = S.A.phys.frame
    if fh is not None:
        forms["frame"] = respond(a, fh)[:, None]
        forms["frame_command"] = respond(other.cmd_acc, fh)[:, None]
    # on a loop (its dominant mode does not ring), the force on the load it holds
    corner = {}
    for w in _loop_corners(S.A):
        hf = S.A.phys.load_force(w)
        if hf is None:
            continue
        for form, src in (("loop", a), ("loop_command", other.cmd_acc)):
            key = f"{form}@{w:g}"
            forms[key] = respond(src, hf)[:, None]
            corner[key] = w
    # each form fitted once: scored on what the draw leaves (``score_draw``), the best kept
    models = {form: S.with_extra(G) for form, G in forms.items()}
    score = {form: -float(m.resid[S.fit] @ m.resid[S.fit]) for form, m in models.items()}
    key = max(forms, key=lambda f: score[f])      # ties: the first, in the order above
    m = models[key]
    form = key.split("@")[0]
    name = "coefficient" if form == "position" else "mm_per_mm_s2"
    # chosen and sized with the plant draw fitted beside it (the only kind: docs/diagnose.md)
    params = {"from_axis": other.ax, name: float(m.theta[-1]), "form": form}
    if key in corner:
        params["corner_hz"] = float(corner[key] / (2 * np.pi))
    return ("cross_coupling", form, params, m, len(forms), 2)
