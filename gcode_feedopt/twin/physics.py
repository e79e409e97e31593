"""The one constructor of an axis's physics: profile → Gaussian impulse response.

Every consumer of the twin's physics (the twin itself, the optimizer's predictors, the virtual
machine's plant draws, the diagnosis, the learned prior) gets it from here, so they all agree.

``twin.physics: modal`` (the default): each measured FRF is fitted with a continuous-time modal
model with the DC gain pinned at 1 (``twin.modal``), each fit gives an impulse response, and the
Gaussian impulse response is their sample mean and covariance. ``twin.physics: bins`` keeps the
raw-bin route (``twin.frf``: the paper's per-bin coefficients or the ensemble of the bins'
responses, ``coef_variance``) with the DC bin pinned at the same gain.

Fits are cached per process by the FRF data's hash: a profile is loaded many times in a run.

``axis_physics`` gathers what the diagnosis knows of each axis (``AxisPhysics``: the mean
response, its uncertainty's factor, the dominant mode and how the members spread it, the
response moved to another mode frequency, the response to a force on the carriage).
"""

from __future__ import annotations

import contextlib
import dataclasses
from dataclasses import dataclass
from typing import Callable
import hashlib
import math
import warnings

import numpy as np
from scipy import stats

from ..errors import ModelWarning, ProfileError
from ..firmware.shaper import shape_axes
from ..vm.effects import dominant_mode_hz
from . import frf as _frf
from .modal import (MIN_SPREAD_MEASUREMENTS, PRIOR_SPREAD_FREQ, PRIOR_SPREAD_WEIGHT, AxisModal,
                    ModalModel, ensemble_impulse, fit_axis, loaded_cov,
                    prior_spread_response_var)

_CACHE: dict = {}


def _key(freq_hz, response, *extra) -> str:
    h = hashlib.sha1()
    h.update(np.ascontiguousarray(freq_hz, float).tobytes())
    h.update(np.ascontiguousarray(response, complex).tobytes())
    h.update(repr(extra).encode())
    return h.hexdigest()


def dc_gain_of(profile) -> float | None:
    """The pinned DC gain (1), or None when the profile says to keep the data's."""
    return None if profile.twin.dc_gain == "fitted" else 1.0


def axis_modal(profile, axis: str, *, warn: bool = True) -> AxisModal:
    """The modal fits of a profile axis's FRF set (cached); warnings go to ``warnings.warn``
    once per set (the CLI prints them as one line each)."""
    ax = profile.axes.get(axis)
    if ax is None or ax.frf is None:
        raise ProfileError(f"profile {profile.name}: axis {axis} has no FRFs; add its FRF files "
                           "(axes.{axis}.frf) or build the profile with `profile build`")
    frf = ax.frf
    dc = dc_gain_of(profile)
    n_taps = profile.twin.n_taps
    k = _key(frf.freq_hz, frf.response, "modal", dc, profile.ts_s, n_taps, ax.effects)
    got = _CACHE.get(k)
    if got is None:
        # the fit, once per FRF set: an extended profile (diagnose's "after", learn's
        # written effects) differs only in the effects applied to it
        k_fit = _key(frf.freq_hz, frf.response, "fit", dc, profile.ts_s, axis, tuple(frf.labels))
        fit = _CACHE.get(k_fit)
        if fit is None:
            try:
                fit = fit_axis(frf.freq_hz, frf.response, frf.labels, axis=axis, dc_gain=dc,
                               nyquist_hz=0.5 / profile.ts_s)
            except ValueError as exc:
                raise ProfileError(f"profile {profile.name}, axis {axis}: {exc}") from None
            _CACHE[k_fit] = fit
        got = apply_effects(fit, ax.effects, profile.ts_s)
        got = dataclasses.replace(got, warnings=got.warnings + _memory_warnings(got, profile.ts_s,
                                                                                n_taps))
        _CACHE[k] = got
        if warn:
            for w in got.warnings:
                warnings.warn(f"profile {profile.name}, axis {axis}: {w}", ModelWarning, stacklevel=2)
    return got


#: a mode that still rings at this fraction of its amplitude after the twin's memory is named
#: (``_memory_warnings``): the impulse response keeps the axis's DC gain and lag exactly
#: (ModalModel.impulse) but not the ringing it cuts off
TAIL_WARN = 0.05


def _memory_warnings(fits: AxisModal, ts_s: float, n_taps: int) -> tuple:
    """One line if the machine's least damped mode outlasts the twin's memory (n_taps·Ts), as
    the median member has it: one member whose fit put a mode at the damping floor (a line
    narrower than its grid step, tests/foreign seed 0's y_3: 61 % left after 1 s where the
    other seven leave ≤ 2 %) says nothing about how long the machine rings."""
    if not fits.fits:
        return ()
    ranked = sorted(((m.tail_envelope(ts_s, n_taps), lab, m)
                     for lab, m in zip(fits.labels, fits.models)), key=lambda p: p[0])
    left, label, model = ranked[len(ranked) // 2]
    if left <= TAIL_WARN:
        return ()
    i = model.slowest_ringing
    z, f = float(model.damping[i]), float(model.freq_hz[i])
    need = int(math.ceil(math.log(100.0) / (2 * math.pi * z * f * ts_s)))
    return (f"{label}: a mode at {f:.1f} Hz (ζ {z:.3f}) still rings at "
            f"{100 * left:.0f} % of its amplitude after the twin's memory of {n_taps} samples "
            f"({n_taps * ts_s:g} s); the twin misses that ringing: set twin.n_taps to at least "
            f"{need} (its ringing down to 1 %)",)


def axis_impulse(profile, axis: str) -> _frf.ImpulseResponse:
    """The Gaussian impulse response of a profile axis (module docstring)."""
    tw = profile.twin
    n_taps = tw.n_taps
    if tw.physics == "modal":
        fits = axis_modal(profile, axis)
        k = _key(profile.axes[axis].frf.freq_hz, profile.axes[axis].frf.response, "ir",
                 dc_gain_of(profile), profile.ts_s, n_taps, profile.axes[axis].effects)
        got = _CACHE.get(k)
        if got is None:
            mean, L = ensemble_impulse(fits.models, profile.ts_s, n_taps,
                                       covs=[ft.cov for ft in fits.fits])
            got = _frf.ImpulseResponse(ts_s=profile.ts_s, mean=mean,
                                       var=np.einsum("ij,ij->i", L, L), factor=L)
            _CACHE[k] = got
        return got
    freq, resp = _bins(profile, axis)
    with _named_axis(profile, axis):
        return _frf.impulse_response(freq, resp, profile.ts_s, n_taps, method=tw.coef_variance)


#: the machine has stopped ringing once its impulse response's envelope is below this fraction
#: of its peak
RING_FRACTION = 0.01


def ring_time_s(profile, axes=("x", "y")) -> float:
    """How long the machine rings after a change of motion, s: the last time at which an axis's
    impulse response — its mean or its spread's standard deviation, whichever is larger — is
    above RING_FRACTION of its peak (at most the twin's memory, n_taps·Ts). Benchmarks built
    from FRFs give 0.16–0.28 s (the built-in profiles, benchA); a corexy whose 26 Hz modes
    have ζ 0.026 rings for 0.94 s (tests/foreign, seed 0)."""
    def envelope(ir):
        env = np.maximum(np.abs(np.asarray(ir.mean, float)), np.sqrt(np.asarray(ir.var, float)))
        return env / env.max()

    return _last_above(profile, axes, envelope)


def settle_time_s(profile, axes=("x", "y")) -> float:
    """How long the machine takes to settle after a step of its command, s: the last time at
    which an axis's step response (the impulse response summed) is off its final value — its
    mean, or its spread's standard deviation, whichever is larger — by more than
    RING_FRACTION of the step. A lightly damped machine settles as it stops ringing (the
    built-in profiles 0.12–0.24 s, within their ring_time_s); a servo whose integral action
    is slow creeps on long after its impulse response has died down: two PID servos on lead
    screws (tests/foreign, seeds 16 and 17) ring for 0.12–0.13 s and settle in 0.30–0.33 s."""
    def envelope(ir):
        step = np.cumsum(np.asarray(ir.mean, float))
        L = np.cumsum(np.asarray(ir.factor, float), axis=0)
        return np.maximum(np.abs(step - step[-1]), np.sqrt(np.einsum("ij,ij->i", L, L)))

    return _last_above(profile, axes, envelope)


def _last_above(profile, axes, envelope) -> float:
    """The latest time, over the axes with FRFs, at which ``envelope(impulse response)`` (an
    (n,) array relative to the step or the peak) is above RING_FRACTION, s."""
    longest = 0.0
    for ax in axes:
        if ax not in profile.axes or profile.axes[ax].frf is None:
            continue
        above = np.nonzero(envelope(axis_impulse(profile, ax)) > RING_FRACTION)[0]
        if above.size:
            longest = max(longest, float(above[-1] + 1) * profile.ts_s)
    return longest


def memory_time_s(profile) -> float:
    """How long a change of motion goes on moving the machine, s: the longer of
    ring_time_s (the impulse response dies down) and settle_time_s (the step response
    settles), plus the span of the firmware's input shaper (its last pulse moves the
    machine that much later). What the slow-down must see out (SlowdownSettings.seeing_out)."""
    span = max((float(np.ptp(sh.pulses()[1])) for sh in profile.firmware.input_shaper.values()),
               default=0.0)
    return max(ring_time_s(profile), settle_time_s(profile)) + span


def machine_command(profile, cmd: np.ndarray, *, segments=None) -> np.ndarray:
    """The motion the machine receives for commanded positions ``cmd`` (K, ≥2), mm: X and Y
    through the firmware's input shaper where the profile has one (firmware.shaper), else
    ``cmd`` itself. The twin's physics acts on this; the contour error is measured against
    ``cmd``."""
    return shape_axes(cmd, profile.ts_s, profile.firmware.input_shaper, segments=segments)


def log_machine_command(profile, log) -> np.ndarray:
    """:func:`machine_command` of a MotionLog's commands: a print's log ran through the
    shaper; a Klipper resonance test's (``kind`` klipper_raw) did not (TEST_RESONANCES turns
    the shaper off unless asked otherwise), so its commands are the machine's input."""
    if log.kind == "klipper_raw":
        return log.cmd_mm
    return machine_command(profile, log.cmd_mm)


def apply_effects(fits: AxisModal, effects, ts_s: float | None = None) -> AxisModal:
    """The fits with a diagnosis's linear extensions applied to every member (a delay, a gain
    about the origin, the dominant mode moved as a mass change moves it, or with form
    ``scale`` the whole response rescaled so the peak of |H| (up to 0.5/ts_s) lands there, or
    with form ``load`` the load of the whole loop heavier, ``ModalModel.loaded``)."""
    if not effects:
        return fits
    new = []
    mm = fits.mean_model()
    dom = mm.dominant
    f_dom = float(mm.freq_hz[dom])
    f_peak = mm.peak_hz(0.5 / ts_s) if ts_s else f_dom
    doms = fits.member_modes(dom)
    for ft, dom_k in zip(fits.fits, doms):
        m, cov = ft.model, ft.cov
        for e in effects:
            p = e["params"]
            if e["kind"] == "delay":
                m = m.delayed(p["delay_s"])
            elif e["kind"] == "gain":
                m = m.scaled(p["scale"])
            elif e["kind"] == "resonance_shift" and p.get("form") == "scale":
                m = m.rescaled(p["frequency_hz"] / f_peak)
            elif e["kind"] == "resonance_shift" and p.get("form") == "load":
                lm = m.loaded(p["load_ratio"], 2 * math.pi * p["corner_hz"])
                if lm is None:
                    raise ProfileError(
                        f"resonance_shift (load {p['load_ratio']:g}, corner "
                        f"{p['corner_hz']:g} Hz) makes a measured FRF's loop unstable; "
                        "diagnose the log again or remove this extension")
                if cov is not None:
                    cov = loaded_cov(m, cov, p["load_ratio"], 2 * math.pi * p["corner_hz"])
                m = lm
            elif e["kind"] == "resonance_shift":
                m = m.mode_shifted(dom_k, p["frequency_hz"] / f_dom)
        new.append(dataclasses.replace(ft, model=m, cov=cov))
    return dataclasses.replace(fits, fits=tuple(new))


def _bins(profile, axis: str):
    """(freq_hz, responses) of the raw-bin route: DC pinned, the axis's extensions applied to
    the rows (delay e^{−j2πfd}, gain ×s, resonance shift H(f·f0/f1), a loaded loop)."""
    ax = profile.axes[axis]
    freq, resp = pinned_bins(ax.frf.freq_hz, ax.frf.response, dc_gain_of(profile))
    for e in ax.effects:
        p = e["params"]
        if e["kind"] == "delay":
            resp = resp * np.exp(-2j * np.pi * freq * p["delay_s"])[None, :]
        elif e["kind"] == "gain":
            resp = resp * p["scale"]
        elif e["kind"] == "resonance_shift" and p.get("form") == "load":
            # the loaded loop bin by bin: H/(1 + ratio·(1 − H)·s/(s + a)) (ModalModel.loaded)
            s = 2j * np.pi * freq[None, :]
            a = 2 * np.pi * p["corner_hz"]
            f_v = s / (s + a) if a > 0 else np.ones_like(s)
            resp = resp / (1.0 + p["load_ratio"] * (1.0 - resp) * f_v)
        elif e["kind"] == "resonance_shift":
            mm = mean_model(profile, axis)
            f0 = (mm.peak_hz(0.5 / profile.ts_s) if p.get("form") == "scale"
                  else float(mm.freq_hz[mm.dominant]))
            resp = _shift_rows(freq, resp, p["frequency_hz"] / f0)
    return freq, resp


@contextlib.contextmanager
def _named_axis(profile, axis: str):
    """A raw-bin constructor's ValueError (a grid too coarse for twin.n_taps) as the
    profile's error, naming the profile and the axis."""
    try:
        yield
    except ValueError as exc:
        raise ProfileError(f"profile {profile.name}, axis {axis} (twin.physics: bins): "
                           f"{exc}") from None


def _shift_rows(freq_hz, rows, ratio):
    """rows (N, F) complex -> H(f / ratio) per row (mode f0 -> ratio·f0), interpolated in
    magnitude and unwrapped phase (outside the grid: the edge value)."""
    f_src = freq_hz / ratio
    out = np.empty_like(rows)
    for i, h in enumerate(rows):
        mag = np.interp(f_src, freq_hz, np.abs(h))
        ph = np.interp(f_src, freq_hz, np.unwrap(np.angle(h)))
        out[i] = mag * np.exp(1j * ph)
    return out


def pinned_bins(freq_hz, response, dc_gain: float | None):
    """The FRF set with a 0 Hz bin of exactly ``dc_gain`` (None: left as measured)."""
    f = np.asarray(freq_hz, float)
    R = np.atleast_2d(np.asarray(response, complex))
    if dc_gain is None:
        return f, R
    if f[0] == 0.0:
        R = R.copy()
        R[:, 0] = dc_gain
        return f, R
    return np.concatenate([[0.0], f]), np.hstack([np.full((R.shape[0], 1), dc_gain, complex), R])


def member_impulses(profile, axis: str) -> np.ndarray:
    """(N_H, n_taps) impulse response of each measured FRF of the axis, as the twin builds them."""
    tw = profile.twin
    if tw.physics == "modal":
        return np.array([m.impulse(profile.ts_s, tw.n_taps) for m in axis_modal(profile, axis).models])
    freq, resp = _bins(profile, axis)
    with _named_axis(profile, axis):
        return _frf.member_impulses(freq, resp, profile.ts_s, tw.n_taps)


def draw_impulses(profile, axis: str, rng: np.random.Generator, size: int = 1) -> np.ndarray:
    """(size, n_taps) plants drawn from the axis's Gaussian impulse response."""
    tw = profile.twin
    if tw.physics == "modal" or tw.coef_variance == "ensemble":
        ir = axis_impulse(profile, axis)
        z = rng.standard_normal((size, ir.factor.shape[1]))
        return ir.mean[None, :] + z @ ir.factor.T
    freq, resp = _bins(profile, axis)
    with _named_axis(profile, axis):
        return _frf.draw_impulse_responses(freq, resp, profile.ts_s, tw.n_taps, rng, size,
                                           method=tw.coef_variance)


def mean_model(profile, axis: str):
    """A representative ModalModel of the axis (the members' parameter mean)."""
    return axis_modal(profile, axis).mean_model()


def with_physics(profile, physics: str):
    """A copy of the profile using ``physics`` (``modal`` | ``bins``)."""
    return dataclasses.replace(profile, twin=dataclasses.replace(profile.twin, physics=physics))


#: Damping below which a dominant mode rings (its move inside the members' spread is
#: scanned, not linearised: ``closedloop.diagnose._absorb_mode``); a closed loop at ζ 0.5–0.8 does not, and its
#: members' "dominant mode" spreads over ±45 % (poorly identified), which a scan would let
#: swallow a real −10 % shift.
RINGING_ZETA = 0.2


@dataclass(frozen=True)
class AxisPhysics:
    """What the diagnosis knows of one axis.

    Attributes:
        mean: (n,) the twin's mean impulse response, unit DC gain.
        factor: (n, r) factor of its covariance (the baseline's directions), may be (n, 0).
        mode_hz: the dominant mode of ``mean``.
        shifted: f1 -> (n,) the response with the dominant mode at f1 as a mass change moves
            it (modal physics), or None (then only the frequency-rescaled form is tried).
        loaded: (ratio, a) -> (n,) the response with the load its loop moves heavier by
            ``ratio`` (``ModalModel.loaded``, corner a rad/s), or None where that loop is
            unstable; None without modal physics.
        loaded_hz: (ratio, a) -> the loaded model's pole pair at its peak
            (``ModalModel.pair_at_peak_hz``), Hz.
        load_force: a -> (n,) the response to a force on that load through the loop
            (``ModalModel.load_force``), scaled so its step response peaks at 1, or None.
        force: (n,) response of the axis to a force on its carriage, unit DC gain: the modes
            without the residues' damping zeros (b1 = 0, no direct part), or None.
        frame: (n,) response of the axis to a force on the frame that carries its motor,
            unit DC gain (``frame_model``), or None where the modal fit has no antiresonance
            to take out or has real poles (a servo's loop: its table force goes through it).
        integral_action: the modal fit has real poles (a pair with ζ > 1), which a position
            loop with integral action (a servo's PID) puts below its bandwidth: such a loop
            washes a steady force out (``twin.extensions.integral_sign``).
        model: the representative modal model (``shifted`` moves its dominant mode), or None.
        members: the FRF members' modal models (their spread is the known uncertainty).
        band_hz: (K,) the measured FRF frequencies, or None.
        mode_span_hz: (lo, hi) of the dominant mode over the members (the same mode in each),
            or None where it does not ring (ζ ≥ RINGING_ZETA) or there is no modal model.
        mode_scan_hz: (lo, hi) where the plant's dominant mode may lie by the known
            uncertainty (``mode_scan_band``): the band the diagnosis scans before it may name
            an effect; None with ``mode_span_hz``.
        mode_zeta: the representative model's damping of that mode.
    """

    mean: np.ndarray
    factor: np.ndarray
    mode_hz: float
    shifted: Callable[[float], np.ndarray] | None = None
    loaded: Callable[[float, float], np.ndarray | None] | None = None
    loaded_hz: Callable[[float, float], float] | None = None
    load_force: Callable[[float], np.ndarray | None] | None = None
    force: np.ndarray | None = None
    frame: np.ndarray | None = None
    mode_span_hz: tuple[float, float] | None = None
    mode_scan_hz: tuple[float, float] | None = None
    mode_zeta: float | None = None
    integral_action: bool = False
    model: ModalModel | None = None
    members: tuple = ()
    band_hz: np.ndarray | None = None

    def move_inside_spread(self, form: str, f1: float, f_peak: float,
                           load: tuple[float, float] | None = None) -> bool:
        """Whether the dominant mode moved to ``f1`` (``form`` "mass": the representative
        model's mode as a mass change moves it; "scale": the members' mean response stretched
        so its peak ``f_peak`` goes to f1) stays where another measurement of the same machine
        could put it (``form`` "load": the representative model's loop loaded by ``load`` =
        (ratio, a), ``ModalModel.loaded``): at every measured frequency f its change |ΔH(f)| is
        within the 95 %
        prediction bound of one more member about the members' mean,
        k_n·s(f), s² = Σ|H_i − H̄|²/(n − 1), k_n² = F₀.₉₅(2, 2(n − 1))·(1 + 1/n) (a complex
        Gaussian deviation, its variance estimated from n members: k 5.3 / 3.0 / 2.5 / 2.0 at
        n = 2 / 3 / 4 / 8). Such a machine is one the profile's own measurements do not tell
        from the population: the known uncertainty, not a change of the machine.

        On a servo (tests/foreign seed 31) whose four members fit its slow poles four ways
        (2–44 Hz, ζ 0.95–4.2) around a 19.2 Hz, ζ 0.43 loop mode, a gain log was named that
        gain and "resonance_shift x 15.3 Hz" beside it, and a clean log "resonance_shift x
        19.02 Hz": a −0.7 % move, where the members put that mode at 18.94–19.33 Hz. The bound
        was the furthest member's deviation until then, which n members' own spread
        understates (the second move left it 1.05 times; 0.47 times this bound). A real
        −12 % shift of seed 17's loop mode leaves this bound 4.7 times over, benchA's −9 %
        shift 22 times; of the foreign machines' named shifts (seeds 0–67) the closest
        is seed 12's servo loop, 1.38 times. Fewer than MIN_SPREAD_MEASUREMENTS members:
        s² blends their spread with a typical machine's (``modal.prior_spread_response_var``)
        as the twin's impulse response does (``modal._with_prior_spread``), a known variance:
        k² = χ²₂(0.95)/2·(1 + 1/n). False when there is nothing to compare (no member, no
        band, or no modal model)."""
        if not self.members or self.band_hz is None or self.model is None:
            return False
        f = np.asarray(self.band_hz, float)
        f = f[f > 0]
        if f.size == 0:
            return False

        def members_mean(freq):
            return np.mean([m.response(freq) for m in self.members], axis=0)

        R = np.array([m.response(f) for m in self.members])
        n, mean = R.shape[0], R.mean(axis=0)
        ss = np.sum(np.abs(R - mean) ** 2, axis=0)
        if n < MIN_SPREAD_MEASUREMENTS:
            s0 = np.mean([prior_spread_response_var(m, f) for m in self.members], axis=0)
            s = np.sqrt((PRIOR_SPREAD_WEIGHT * s0 + ss) / (PRIOR_SPREAD_WEIGHT + n - 1))
            k = math.sqrt(stats.chi2.ppf(0.95, 2) / 2 * (1.0 + 1.0 / n))
        else:
            s = np.sqrt(ss / (n - 1))
            k = math.sqrt(stats.f.ppf(0.95, 2, 2 * (n - 1)) * (1.0 + 1.0 / n))
        if form == "load":
            moved = self.model.loaded(*load)
            if moved is None:
                return False
            change = moved.response(f) - self.model.response(f)
        elif form == "mass":
            dom = self.model.dominant
            moved = self.model.mode_shifted(dom, f1 / float(self.model.freq_hz[dom]))
            change = moved.response(f) - self.model.response(f)
        else:
            change = members_mean(f * f_peak / f1) - mean
        return bool(np.all(np.abs(change) <= k * s))


def nominal_impulse(profile) -> dict:
    """axis -> (mean (n,), factor (n, r)) of the twin's impulse response, unit DC gain."""
    out = {}
    for ax in ("x", "y"):
        ir = axis_impulse(profile, ax)
        s = float(np.sum(ir.mean))
        out[ax] = (np.asarray(ir.mean) / s, np.asarray(ir.factor) / s)
    return out


def mode_scan_band(span: tuple[float, float], f_hz: float, n: int) -> tuple[float, float]:
    """Where the plant's dominant mode may lie, from its members' range ``span`` (n members)
    about the representative model's ``f_hz``: the range widened by half its width on each
    side (n members' min–max understates the population's, and the plant of the logs is not
    one of them: a foreign belt machine's members at 49.0–50.4 Hz left a clean log's mode at
    49.7 Hz unexplained until the whole band was scanned). Fewer than
    MIN_SPREAD_MEASUREMENTS members cannot span it: the band also covers the 95 % band of
    one more draw of a typical machine's spread about ``f_hz`` (PRIOR_SPREAD_FREQ, as the
    impulse response's factor carries it; ``modal._with_prior_spread``): with the members'
    spread alone, clean logs of machines measured once were named resonance shifts; a band
    twice as wide (±8 %) hid a corexy's real −8.6 % shift."""
    lo, hi = span
    half = 0.5 * (hi - lo)
    lo, hi = lo - half, hi + half
    if n < MIN_SPREAD_MEASUREMENTS:
        w = stats.norm.ppf(0.975) * PRIOR_SPREAD_FREQ * math.sqrt(1 + 1 / n)
        lo, hi = min(lo, f_hz * math.exp(-w)), max(hi, f_hz * math.exp(w))
    return lo, hi


def axis_physics(profile) -> dict:
    """axis -> AxisPhysics of a profile: what ``closedloop.diagnose`` and the force form of
    ``twin.extensions`` know of each axis."""
    imp = nominal_impulse(profile)
    out = {}
    for ax in ("x", "y"):
        mean, L = imp[ax]
        shifted = loaded = loaded_hz = load_force = None
        key = None
        if profile.twin.physics == "modal":
            # cached with its closures' caches: each log a diagnosis reads, and each round of
            # it, scans the same moved and loaded responses (keyed as axis_impulse's)
            frf = profile.axes[ax].frf
            key = _key(frf.freq_hz, frf.response, "phys", dc_gain_of(profile), profile.ts_s,
                     profile.twin.n_taps, profile.axes[ax].effects)
            if key in _CACHE:
                out[ax] = _CACHE[key]
                continue
            fits = axis_modal(profile, ax)
            mm = fits.mean_model()
            dom = mm.dominant
            f_dom = float(mm.freq_hz[dom])
            ts, n = profile.ts_s, mean.size
            # the members' mean response with the representative model's dominant mode moved:
            # h̄ − h_mm(f_dom) + h_mm(f1), exact for the representative model, cached per f1
            h_mm = mm.impulse(ts, n)
            cache = {}

            def shifted(f1, mm=mm, dom=dom, f_dom=f_dom, ts=ts, n=n, h_mm=h_mm, mean=mean,
                        cache=cache):
                key = round(float(f1), 6)
                if key not in cache:
                    h = mean - h_mm / np.sum(h_mm) + mm.mode_shifted(dom, f1 / f_dom).impulse(ts, n) / np.sum(h_mm)
                    cache[key] = h / np.sum(h)
                return cache[key]

            f_top = min(400.0, 0.5 / ts)

            lmodels, lcache = {}, {}

            def loaded_model(ratio, a, mm=mm, cache=lmodels):
                key = (round(float(ratio), 9), round(float(a), 6))
                if key not in cache:
                    cache[key] = mm.loaded(ratio, a)
                return cache[key]

            def loaded(ratio, a, ts=ts, n=n, h_mm=h_mm, mean=mean, cache=lcache,
                       loaded_model=loaded_model):
                key = (round(float(ratio), 9), round(float(a), 6))
                if key not in cache:
                    lm = loaded_model(ratio, a)
                    h = None if lm is None else (mean - h_mm / np.sum(h_mm)
                                                 + lm.impulse(ts, n) / np.sum(h_mm))
                    cache[key] = None if h is None else h / np.sum(h)
                return cache[key]

            fcache = {}

            def load_force(a, mm=mm, ts=ts, n=n, cache=fcache):
                key = round(float(a), 6)
                if key not in cache:
                    fm = mm.load_force(a)
                    h = None if fm is None else fm.impulse(ts, n)
                    peak = 0.0 if h is None else float(np.max(np.abs(np.cumsum(h))))
                    cache[key] = h / peak if peak > 0 and np.isfinite(peak) else None
                return cache[key]

            def loaded_hz(ratio, a, f_top=f_top, loaded_model=loaded_model):
                lm = loaded_model(ratio, a)
                return math.nan if lm is None else lm.pair_at_peak_hz(1.0, f_top)

            mode = f_dom
            force = _force_response(mm, ts, n)
            band = np.asarray(profile.axes[ax].frf.freq_hz, float)
            frame = None
            if not np.any(mm.damping >= 1.0):
                frame = _frame_response(mm, ts, n, float(np.max(band)))
            # the members' own dominant modes: how far the known uncertainty moves it
            # (the same mode in each, matched mode to mode: AxisModal.member_modes; which mode
            # is largest may differ between members of two near-equal modes)
            doms = [float(ft.model.freq_hz[k]) for ft, k in zip(fits.fits, fits.member_modes(dom))
                    if ft.model.b0[k] != 0 or ft.model.b1_rad_s[k] != 0] or [f_dom]
            span = scan = None
            if mm.damping[dom] < RINGING_ZETA:
                span = (min(doms), max(doms))
                scan = mode_scan_band(span, f_dom, len(fits.fits))
            zeta = float(mm.damping[dom])
            integral = bool(np.any(mm.damping > 1.0))
            model, members = mm, tuple(ft.model for ft in fits.fits)
        else:
            model, members, band = None, (), None
            mode = dominant_mode_hz(mean, profile.ts_s)
            force = frame = None
            span = scan = zeta = None
            integral = False
        out[ax] = AxisPhysics(mean=mean, factor=L, mode_hz=mode, shifted=shifted,
                              loaded=loaded, loaded_hz=loaded_hz, load_force=load_force,
                              force=force,
                              frame=frame,
                              mode_span_hz=span, mode_scan_hz=scan, mode_zeta=zeta,
                              integral_action=integral,
                              model=model, members=members, band_hz=band)
        if key is not None:
            _CACHE[key] = out[ax]
    return out


def _force_response(model, ts_s: float, n_taps: int):
    """(n,) unit-DC response of a modal model's modes to a force (module docstring of
    AxisPhysics), or None when the modes carry no static share."""
    g = float(np.sum(model.b0))
    if not np.isfinite(g) or g <= 0.1:
        return None
    mf = ModalModel(model.freq_hz, model.damping, np.zeros_like(model.b1_rad_s), model.b0,
                    lag_s=0.0, dc_gain=g, delay_s=0.0)
    h = mf.impulse(ts_s, n_taps)
    return h / np.sum(h)


#: damping above which a complex zero pair of a modal fit is no antiresonance (``frame_model``)
ANTIRESONANCE_ZETA = 0.3


def _frame_response(model, ts_s: float, n_taps: int, band_hi_hz: float):
    """(n,) unit-DC impulse response of ``frame_model``, or None where it is None."""
    mf = frame_model(model, band_hi_hz)
    if mf is None:
        return None
    h = mf.impulse(ts_s, n_taps)
    return h / np.sum(h)


def frame_model(model, band_hi_hz: float):
    """The axis's response to a force on the frame that carries its motor, unit DC gain: a
    ModalModel with ``model``'s modes, or None.

    The command enters a belt drive between the frame and the carriage: the motor pulls the
    belt against the frame it sits on. Seen from the command, the frame is a side branch of
    the chain, and the chain's response has a zero pair where that branch alone would
    resonate (the measured FRF's antiresonance). A force on the frame enters at the end of
    the chain (frame, belt, carriage, hotend): its response has the same poles without that
    pair (undamped, a chain driven at one end and sensed at the other has no zeros; the
    springs' dampers leave real zeros far above the modes, which stay). So: ``model`` with
    its lowest lightly damped (ζ < ANTIRESONANCE_ZETA), minimum-phase complex zero pair at
    or below ``band_hi_hz`` (the measured band's top) taken out, and without the first-order
    lag of the command path (the motor's). None where the model has no such pair, or the
    rest is no response (its static share ≤ 0.1). On the belt machines of tests/foreign the
    fits put that zero within 0.5 % of the frame's own frequency (seeds 800–806). A servo's
    table force enters through its PID loop: ``axis_physics`` does not ask for it there."""
    w = 2 * np.pi * np.asarray(model.freq_hz, float)
    z = np.asarray(model.damping, float)
    if w.size == 0:
        return None
    w0 = float(np.max(w))                       # polynomials in s / w0: well scaled
    wn = w / w0
    dens = [np.array([1.0, 2 * zi * wi, wi * wi]) for wi, zi in zip(wn, z)]

    def prod(ps):
        out = np.array([1.0])
        for q in ps:
            out = np.polymul(out, q)
        return out

    num = model.direct * prod(dens)
    for i, (b1, b0) in enumerate(zip(model.b1_rad_s, model.b0)):
        num = np.polyadd(num, np.polymul([b1 / w0, b0 * wn[i] ** 2],
                                         prod(d for j, d in enumerate(dens) if j != i)))
    num = np.trim_zeros(num, "f")
    if num.size < 3:
        return None
    cand = [r for r in np.roots(num) if r.imag > 1e-9 and r.real < 0
            and -r.real / abs(r) < ANTIRESONANCE_ZETA and abs(r) * w0 / (2 * np.pi) <= band_hi_hz]
    if not cand:
        return None
    r = min(cand, key=abs)
    num2, _ = np.polydiv(num, np.array([1.0, -2 * r.real, abs(r) ** 2]))
    # partial fractions of num2 / Π dens, mode by mode: b1·s + b0·w² at both roots of its pair
    b1 = np.zeros(w.size)
    b0 = np.zeros(w.size)
    with np.errstate(all="ignore"):
        for i, d in enumerate(dens):
            p = np.roots(d)
            rest = prod(dd for j, dd in enumerate(dens) if j != i)
            rhs = np.polyval(num2, p) / np.polyval(rest, p)
            if not np.all(np.isfinite(rhs)):          # a repeated pole: no such fraction
                return None
            M = np.column_stack([p, np.full(2, wn[i] ** 2)]).astype(complex)
            sol = np.linalg.lstsq(M, rhs, rcond=None)[0]
            b1[i], b0[i] = np.real(sol[0]) * w0, np.real(sol[1])
    g = float(np.sum(b0))
    if not np.all(np.isfinite(b1)) or not np.isfinite(g) or g <= 0.1:
        return None
    return ModalModel(model.freq_hz, model.damping, b1 / g, b0 / g, lag_s=0.0, dc_gain=1.0,
                      delay_s=0.0)
