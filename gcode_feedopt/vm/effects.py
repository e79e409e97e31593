"""Unknown effects the virtual machine's plant can plant in its output.

The twin knows the machine only through its FRF distribution (the *known* uncertainty). Real
machines also have effects no FRF shows; these are them, the catalogue ``diagnose`` must find
(issue 6). Each effect is a frozen dataclass that applies to one named axis (``"x"`` or ``"y"``)
and has a one-line SPEC form for ``--effect``::

    periodic_time:axis=x,frequency_hz=116.7,amplitude_mm=0.05
    sinusoid:axis=x,amp_mm=0.2,omega_rad_s=733        (the paper's x_f = A_f sin(w_f t), Sec. 5)
    periodic_position:axis=y,wavelength_mm=40,amplitude_mm=0.03
    backlash:axis=x,magnitude_mm=0.05
    friction:axis=x,amplitude_mm=0.02
    delay:axis=y,delay_s=0.004
    gain:axis=x,scale=1.01
    resonance_shift:axis=x,frequency_hz=45
    cross_coupling:axis=y,from_axis=x,coefficient=0.01
    noise:axis=x,std_mm=0.002

What each one does, and where the plant applies it (``STAGES``, in this order):

1. ``response`` — ``resonance_shift``: the dominant mode of the drawn impulse response (the
   peak of |H| above 1 Hz, f0) moves to ``frequency_hz`` (f1) by re-scaling the response's
   frequency axis, H'(f) = H(f·f0/f1), i.e. the time axis of h (see
   ``rescale_impulse_response``). Every feature of h (a second mode too) moves by f1/f0.
2. ``linear`` — after the convolution: ``gain`` scales the position about the machine origin
   (a steps/mm error: x = scale·x_m); ``delay`` shifts the output later by ``delay_s``
   (linear interpolation between samples; the first value is held before the start).
3. ``coupling`` — ``cross_coupling``: the ``from_axis``'s motion (its stage-2 output minus its
   initial position) leaks into ``axis`` times ``coefficient``. Sources are taken before any
   coupling is added, so two couplings never feed each other.
4. ``nonlinear`` — ``backlash``: a play (dead band) of width ``magnitude_mm`` between the servo
   and the load: the load moves only when the servo has taken up the play, so after a reversal
   it stands still for ``magnitude_mm`` of servo travel and then trails by ``magnitude_mm``
   (the band starts centred: the load starts at the servo's initial position). ``friction``:
   Coulomb friction as a following error ``-amplitude_mm·sign(v_cmd)`` against the commanded
   velocity (zero at rest, |v| < ``REST_SPEED_MM_S``).
5. ``additive`` — ``periodic_time``: ``amplitude_mm·sin(2π·frequency_hz·t + phase_rad)``;
   ``periodic_position``: ``amplitude_mm·sin(2π·x_cmd/wavelength_mm + phase_rad)``, a function
   of the *commanded* axis position (lead-screw or pulley runout).
6. ``sensor`` — ``noise``: Gaussian sensor noise of ``std_mm``; it is in the *measured* signal
   (the log) only, never in the true position the metrics judge.

Effects of the same stage apply in the order given. The functions here are pure and work on
arrays; ``vm.plant`` calls them.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import ClassVar

import numpy as np
from scipy.interpolate import CubicSpline

from ..errors import FeedOptError

#: The order in which the plant applies effect stages (see the module docstring).
STAGES = ("response", "linear", "coupling", "nonlinear", "additive", "sensor")

#: Axes an effect may name. Z is passed through ideally by the plant, so effects on it are refused.
EFFECT_AXES = ("x", "y")

#: Below this commanded speed an axis counts as at rest for Coulomb friction, mm/s. Far below
#: any real feed and far above the round-off of a finite difference of positions in mm.
REST_SPEED_MM_S = 1e-6


class EffectSpecError(FeedOptError):
    """An ``--effect`` SPEC string cannot be parsed or is out of bounds."""


@dataclass(frozen=True)
class Effect:
    """Base class. ``axis`` is ``"x"`` or ``"y"``; subclasses add their parameters."""

    axis: str
    kind: ClassVar[str] = ""
    stage: ClassVar[str] = ""

    def params(self) -> dict:
        """Parameters without ``axis``, as in diagnose's JSON (``{"frequency_hz": ..}``)."""
        d = asdict(self)
        d.pop("axis")
        return d

    def to_dict(self) -> dict:
        """``{"kind": .., "axis": .., "params": {..}}`` (the shape of diagnose's ``effects``)."""
        return {"kind": self.kind, "axis": self.axis, "params": self.params()}

    def to_spec(self) -> str:
        """The canonical SPEC string; ``parse_effect(e.to_spec()) == e``."""
        parts = [f"axis={self.axis}"] + [f"{k}={v!r}" if isinstance(v, float) else f"{k}={v}"
                                          for k, v in self.params().items()]
        return f"{self.kind}:" + ",".join(parts)

    def _check(self):  # overridden by subclasses with bounds
        pass

    def __post_init__(self):
        if self.axis not in EFFECT_AXES:
            raise EffectSpecError(
                f"{self.kind}: axis={self.axis!r} is not supported; use one of "
                f"{', '.join(EFFECT_AXES)} (Z is passed through ideally)")
        self._check()


def _positive(kind: str, name: str, value: float, fix: str = ""):
    if not (math.isfinite(value) and value > 0):
        raise EffectSpecError(f"{kind}: {name}={value} must be a finite number > 0{fix}")


def _finite(kind: str, name: str, value: float):
    if not math.isfinite(value):
        raise EffectSpecError(f"{kind}: {name}={value} must be a finite number")


@dataclass(frozen=True)
class PeriodicTime(Effect):
    """x += amplitude_mm · sin(2π · frequency_hz · t + phase_rad); the paper's force-induced
    servo error x_f = A_f sin(ω_f t) (Sec. 5, A_f = 0.2, ω_f = 733 rad/s) is one of these."""

    frequency_hz: float = 0.0
    amplitude_mm: float = 0.0
    phase_rad: float = 0.0
    kind: ClassVar[str] = "periodic_time"
    stage: ClassVar[str] = "additive"

    def _check(self):
        _positive(self.kind, "frequency_hz", self.frequency_hz)
        _finite(self.kind, "amplitude_mm", self.amplitude_mm)
        _finite(self.kind, "phase_rad", self.phase_rad)

    def apply(self, x_mm: np.ndarray, t_s: np.ndarray) -> np.ndarray:
        return x_mm + self.amplitude_mm * np.sin(2 * np.pi * self.frequency_hz * t_s + self.phase_rad)


@dataclass(frozen=True)
class PeriodicPosition(Effect):
    """x += amplitude_mm · sin(2π · x_cmd / wavelength_mm + phase_rad), x_cmd the commanded
    position of the same axis (lead-screw pitch or belt-pulley runout)."""

    wavelength_mm: float = 0.0
    amplitude_mm: float = 0.0
    phase_rad: float = 0.0
    kind: ClassVar[str] = "periodic_position"
    stage: ClassVar[str] = "additive"

    def _check(self):
        _positive(self.kind, "wavelength_mm", self.wavelength_mm)
        _finite(self.kind, "amplitude_mm", self.amplitude_mm)
        _finite(self.kind, "phase_rad", self.phase_rad)

    def apply(self, x_mm: np.ndarray, cmd_mm: np.ndarray) -> np.ndarray:
        return x_mm + self.amplitude_mm * np.sin(2 * np.pi * cmd_mm / self.wavelength_mm + self.phase_rad)


@dataclass(frozen=True)
class Backlash(Effect):
    """A play of width magnitude_mm between servo and load (see ``play``)."""

    magnitude_mm: float = 0.0
    kind: ClassVar[str] = "backlash"
    stage: ClassVar[str] = "nonlinear"

    def _check(self):
        _positive(self.kind, "magnitude_mm", self.magnitude_mm)

    def apply(self, x_mm: np.ndarray) -> np.ndarray:
        return play(x_mm, self.magnitude_mm)


@dataclass(frozen=True)
class Friction(Effect):
    """Coulomb friction as a following error: x -= amplitude_mm · sign(v_cmd)."""

    amplitude_mm: float = 0.0
    kind: ClassVar[str] = "friction"
    stage: ClassVar[str] = "nonlinear"

    def _check(self):
        _positive(self.kind, "amplitude_mm", self.amplitude_mm)

    def apply(self, x_mm: np.ndarray, cmd_mm: np.ndarray, ts_s: float) -> np.ndarray:
        return x_mm - self.amplitude_mm * velocity_sign(cmd_mm, ts_s)


@dataclass(frozen=True)
class Delay(Effect):
    """The axis responds delay_s later than the model says."""

    delay_s: float = 0.0
    kind: ClassVar[str] = "delay"
    stage: ClassVar[str] = "linear"

    def _check(self):
        _positive(self.kind, "delay_s", self.delay_s)
        if self.delay_s > 1.0:
            raise EffectSpecError(f"delay: delay_s={self.delay_s} exceeds the limit 1.0 s; "
                                  "a servo delay is milliseconds")

    def apply(self, x_mm: np.ndarray, ts_s: float) -> np.ndarray:
        return delay_signal(x_mm, self.delay_s, ts_s)


@dataclass(frozen=True)
class Gain(Effect):
    """x = scale · x_m about the machine origin (a steps/mm calibration error)."""

    scale: float = 1.0
    kind: ClassVar[str] = "gain"
    stage: ClassVar[str] = "linear"

    def _check(self):
        _positive(self.kind, "scale", self.scale)

    def apply(self, x_mm: np.ndarray) -> np.ndarray:
        return self.scale * x_mm


@dataclass(frozen=True)
class ResonanceShift(Effect):
    """The dominant mode of the drawn impulse response moves to frequency_hz."""

    frequency_hz: float = 0.0
    kind: ClassVar[str] = "resonance_shift"
    stage: ClassVar[str] = "response"

    def _check(self):
        _positive(self.kind, "frequency_hz", self.frequency_hz)

    def apply(self, h: np.ndarray, ts_s: float, mode_hz: float | None = None) -> np.ndarray:
        """Shape (n,) -> (n',): h with its mode (``mode_hz``, else the peak of |H|) moved."""
        f0 = dominant_mode_hz(h, ts_s) if mode_hz is None else mode_hz
        nyquist = 0.5 / ts_s
        if self.frequency_hz >= nyquist:
            raise EffectSpecError(f"resonance_shift: frequency_hz={self.frequency_hz} is at or "
                                  f"above the Nyquist frequency {nyquist:g} Hz of Ts={ts_s} s")
        return rescale_impulse_response(h, self.frequency_hz / f0)


@dataclass(frozen=True)
class CrossCoupling(Effect):
    """x += coefficient · (y_m − y_m[0]): motion of from_axis leaks into axis."""

    from_axis: str = ""
    coefficient: float = 0.0
    kind: ClassVar[str] = "cross_coupling"
    stage: ClassVar[str] = "coupling"

    def _check(self):
        if self.from_axis not in EFFECT_AXES or self.from_axis == self.axis:
            raise EffectSpecError(
                f"cross_coupling: from_axis={self.from_axis!r} must be the other axis of "
                f"{', '.join(EFFECT_AXES)} (axis={self.axis})")
        _finite(self.kind, "coefficient", self.coefficient)
        if abs(self.coefficient) >= 1:
            raise EffectSpecError(f"cross_coupling: |coefficient|={abs(self.coefficient)} must "
                                  "be below 1 (a leak, not a second drive)")

    def apply(self, x_mm: np.ndarray, source_mm: np.ndarray) -> np.ndarray:
        return x_mm + self.coefficient * (source_mm - source_mm[0])


@dataclass(frozen=True)
class SensorNoise(Effect):
    """Gaussian noise of std_mm on the measured (logged) position only."""

    std_mm: float = 0.0
    kind: ClassVar[str] = "noise"
    stage: ClassVar[str] = "sensor"

    def _check(self):
        _positive(self.kind, "std_mm", self.std_mm)

    def apply(self, x_mm: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        return x_mm + rng.normal(0.0, self.std_mm, size=x_mm.shape)


#: kind -> class
EFFECT_TYPES: dict[str, type[Effect]] = {
    cls.kind: cls for cls in (PeriodicTime, PeriodicPosition, Backlash, Friction, Delay, Gain,
                              ResonanceShift, CrossCoupling, SensorNoise)
}

#: Accepted alternative keys in a SPEC -> (canonical key, factor)
_ALIASES: dict[str, tuple[str, float]] = {
    "amp_mm": ("amplitude_mm", 1.0),
    "freq_hz": ("frequency_hz", 1.0),
    "omega_rad_s": ("frequency_hz", 1.0 / (2 * np.pi)),
    "seconds": ("delay_s", 1.0),
    "delay_ms": ("delay_s", 1e-3),
    "std": ("std_mm", 1.0),
}

#: The paper's force-induced sinusoid (Sec. 5): A_f = 0.2 mm, ω_f = 733 rad/s (7000 rpm).
PAPER_SINUSOID = {"amplitude_mm": 0.2, "frequency_hz": 733.0 / (2 * np.pi)}


def _closest(word: str, options) -> str:
    import difflib

    hit = difflib.get_close_matches(word, list(options), n=1)
    return f" (did you mean {hit[0]!r}?)" if hit else ""


def parse_effect(spec: str) -> Effect:
    """Parse a SPEC string ``kind:key=value,...`` into an Effect.

    ``sinusoid`` is the paper's force-induced error: a ``periodic_time`` whose amplitude and
    frequency default to A_f = 0.2 mm and ω_f = 733 rad/s. Raises EffectSpecError.
    """
    text = spec.strip()
    kind, sep, rest = text.partition(":")
    kind = kind.strip()
    values: dict[str, object] = {}
    if kind == "sinusoid":
        values.update(PAPER_SINUSOID)
        cls: type[Effect] = PeriodicTime
    elif kind in EFFECT_TYPES:
        cls = EFFECT_TYPES[kind]
    else:
        raise EffectSpecError(f"--effect {spec!r}: unknown kind {kind!r}{_closest(kind, [*EFFECT_TYPES, 'sinusoid'])}; "
                              f"known: sinusoid, {', '.join(EFFECT_TYPES)}")
    names = {f.name: f for f in fields(cls)}
    for item in filter(None, (p.strip() for p in rest.split(","))) if sep else ():
        key, eq, raw = item.partition("=")
        key, raw = key.strip(), raw.strip()
        if not eq or not raw:
            raise EffectSpecError(f"--effect {spec!r}: {item!r} is not key=value; write e.g. "
                                  f"{kind}:axis=x,...")
        factor = 1.0
        if key in _ALIASES and key not in names:
            key, factor = _ALIASES[key]
        if key not in names:
            raise EffectSpecError(f"--effect {spec!r}: {cls.kind} has no parameter {key!r}"
                                  f"{_closest(key, names)}; parameters: {', '.join(names)}")
        if key in ("axis", "from_axis"):
            values[key] = raw.lower()
        else:
            try:
                values[key] = float(raw) * factor
            except ValueError:
                raise EffectSpecError(f"--effect {spec!r}: {key}={raw!r} is not a number") from None
    required = [n for n in names if n not in values and n != "phase_rad"]
    if required:
        raise EffectSpecError(f"--effect {spec!r}: missing {', '.join(required)}; "
                              f"e.g. {_example(cls)}")
    return cls(**values)


def _example(cls: type[Effect]) -> str:
    examples = {
        "periodic_time": "periodic_time:axis=x,frequency_hz=116.7,amplitude_mm=0.05",
        "periodic_position": "periodic_position:axis=y,wavelength_mm=40,amplitude_mm=0.03",
        "backlash": "backlash:axis=x,magnitude_mm=0.05",
        "friction": "friction:axis=x,amplitude_mm=0.02",
        "delay": "delay:axis=y,delay_s=0.004",
        "gain": "gain:axis=x,scale=1.01",
        "resonance_shift": "resonance_shift:axis=x,frequency_hz=45",
        "cross_coupling": "cross_coupling:axis=y,from_axis=x,coefficient=0.01",
        "noise": "noise:axis=x,std_mm=0.002",
    }
    return examples[cls.kind]


def effect_from_dict(d: dict) -> Effect:
    """Inverse of ``Effect.to_dict``."""
    kind = d.get("kind")
    if kind not in EFFECT_TYPES:
        raise EffectSpecError(f"effect {d!r}: unknown kind {kind!r}; known: {', '.join(EFFECT_TYPES)}")
    return EFFECT_TYPES[kind](axis=d.get("axis"), **d.get("params", {}))


# ---------------------------------------------------------------------------------------------
# Pure numerical helpers


def play(x_mm: np.ndarray, width_mm: float) -> np.ndarray:
    """The play (backlash) operator, shape (K,) -> (K,).

    y_k = min(x_k + r, max(x_k − r, y_{k−1})), r = width/2, y_0 = x_0: the load stays put
    until the servo has crossed the band, then trails it by r. Runs of monotone x are done at
    once (inside a rising run y_k = max(y_start, x_k − r)), so the Python loop is over
    reversals, not samples.
    """
    x = np.asarray(x_mm, dtype=float)
    r = 0.5 * width_mm
    if x.size == 0:
        return x.copy()
    dx = np.diff(x)
    nz = np.flatnonzero(dx)
    y = np.empty_like(x)
    if nz.size == 0:
        y[:] = x[0]
        return y
    # direction of each step, steps of 0 inherit the previous non-zero direction
    direction = np.sign(dx)
    idx = np.zeros(dx.size, dtype=np.int64)
    idx[nz] = nz
    np.maximum.accumulate(idx, out=idx)
    direction = direction[idx]
    direction[: nz[0]] = direction[nz[0]]
    # run boundaries: sample indices where the direction changes
    change = np.flatnonzero(direction[1:] != direction[:-1]) + 1
    starts = np.concatenate(([0], change))
    ends = np.concatenate((change, [dx.size]))  # run i covers samples starts[i]..ends[i]
    y_prev = x[0]
    y[0] = x[0]
    for s, e, d in zip(starts.tolist(), ends.tolist(), direction[starts].tolist()):
        seg = x[s + 1:e + 1]
        if d > 0:
            out = np.maximum(seg - r, y_prev)
        else:
            out = np.minimum(seg + r, y_prev)
        y[s + 1:e + 1] = out
        y_prev = out[-1]
    return y


def velocity_sign(cmd_mm: np.ndarray, ts_s: float) -> np.ndarray:
    """Shape (K,). sign of the commanded velocity (central difference), 0 at rest."""
    v = np.gradient(np.asarray(cmd_mm, dtype=float), ts_s) if cmd_mm.size > 1 else np.zeros(cmd_mm.shape)
    s = np.sign(v)
    s[np.abs(v) < REST_SPEED_MM_S] = 0.0
    return s


def delay_signal(x_mm: np.ndarray, delay_s: float, ts_s: float) -> np.ndarray:
    """Shape (K,). x delayed by delay_s (fractional samples by linear interpolation); the first
    value is held before the start."""
    k = np.arange(x_mm.size, dtype=float)
    return np.interp(k - delay_s / ts_s, k, x_mm, left=x_mm[0])


def dominant_mode_hz(h: np.ndarray, ts_s: float, n_fft: int = 1 << 14) -> float:
    """Frequency of the largest peak of |H(f)| above DC, Hz, H the DFT of the impulse response
    h (shape (n,)). Searched above 1 Hz (below that is the DC gain plateau)."""
    H = np.abs(np.fft.rfft(h, n=max(n_fft, h.size)))
    f = np.fft.rfftfreq(max(n_fft, h.size), ts_s)
    band = f >= 1.0
    return float(f[band][np.argmax(H[band])])


def rescale_impulse_response(h: np.ndarray, ratio: float) -> np.ndarray:
    """Shape (n,) -> (n',). The response with its time axis divided by ``ratio``: every
    frequency feature (modes, H'(f) = H(f / ratio)) multiplied by ``ratio``.

    Done on the step response y = cumsum(h), y'(k) = y(k·ratio) by cubic-spline interpolation
    (linear interpolation errs by ~3 % of the peak tap on a 40 Hz mode at Ts = 2 ms), then
    h' = diff(y'): a step-invariant h (h[k] = y(kTs) − y((k−1)Ts)) stays step-invariant, and
    the DC gain sum(h) is kept exactly. n' = ceil((n − 1)/ratio) + 1.
    """
    h = np.asarray(h, dtype=float)
    n = h.size
    y = np.cumsum(h)
    n_out = int(math.ceil((n - 1) / ratio)) + 1
    t = np.arange(n_out) * ratio
    y_out = np.full(n_out, y[-1])
    inside = t <= n - 1
    if n >= 4:
        y_out[inside] = CubicSpline(np.arange(n), y)(t[inside])
    else:
        y_out[inside] = np.interp(t[inside], np.arange(n), y)
    return np.diff(y_out, prepend=0.0)


def random_effect(rng: np.random.Generator, kind: str | None = None, axis: str | None = None,
                  mode_hz: float | None = None) -> Effect:
    """One effect with realistic random parameters (for tests that hide an effect).

    Ranges: periodic_time 5–120 Hz, 0.02–0.08 mm; periodic_position 2–40 mm wavelength (lead
    screw to GT2 pulley), 0.02–0.06 mm; backlash 0.03–0.15 mm; friction 0.01–0.05 mm; delay
    2–20 ms; gain 1 ± (0.5–3) %; resonance_shift 0.7–0.85 or 1.15–1.3 × ``mode_hz`` (required
    for that kind); cross_coupling ±(0.5–3) %.
    """
    kinds = [k for k in EFFECT_TYPES if k != "noise" and (k != "resonance_shift" or mode_hz)]
    kind = kind or kinds[int(rng.integers(len(kinds)))]
    axis = axis or EFFECT_AXES[int(rng.integers(2))]
    sign = 1.0 if rng.random() < 0.5 else -1.0
    u = rng.uniform
    if kind == "periodic_time":
        return PeriodicTime(axis, frequency_hz=u(5, 120), amplitude_mm=u(0.02, 0.08))
    if kind == "periodic_position":
        return PeriodicPosition(axis, wavelength_mm=u(2, 40), amplitude_mm=u(0.02, 0.06))
    if kind == "backlash":
        return Backlash(axis, magnitude_mm=u(0.03, 0.15))
    if kind == "friction":
        return Friction(axis, amplitude_mm=u(0.01, 0.05))
    if kind == "delay":
        return Delay(axis, delay_s=u(0.002, 0.02))
    if kind == "gain":
        return Gain(axis, scale=1.0 + sign * u(0.005, 0.03))
    if kind == "resonance_shift":
        if not mode_hz:
            raise ValueError("random_effect: resonance_shift needs mode_hz (the nominal mode)")
        ratio = u(1.15, 1.3) if sign > 0 else u(0.7, 0.85)
        return ResonanceShift(axis, frequency_hz=ratio * mode_hz)
    if kind == "cross_coupling":
        return CrossCoupling(axis, from_axis="y" if axis == "x" else "x", coefficient=sign * u(0.005, 0.03))
    if kind == "noise":
        return SensorNoise(axis, std_mm=u(0.001, 0.005))
    raise ValueError(f"random_effect: unknown kind {kind!r}")
