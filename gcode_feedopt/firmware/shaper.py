"""Input shaping: the firmware's filter between its planner and the motors.

A shaper replaces the planned position u(t) of an axis by Σ aᵢ u(t − tᵢ): pulses of
amplitudes aᵢ (Σ aᵢ = 1) at times tᵢ, chosen so that a mode at the shaper's frequency and
damping is not excited (its residual vibration, :func:`residual_vibration`, is 0, or a small
tolerance for the insensitive shapers). The machine then receives the shaped motion; our twin's
FRFs describe the machine alone (Klipper's TEST_RESONANCES measures with the shaper off), so
its input is the shaped command (``twin.physics.machine_command``).

The pulse trains are the textbook ones (Singer & Seering 1990: ZV, ZVD; Singhose et al.:
the extra-insensitive EI for a 5 % vibration tolerance, as a polynomial in the damping ratio;
the modified ZV with pulses at 0, 3/8 and 3/4 of the damped period), in the parametrisation
the firmware documents (frequency, damping ratio; Klipper's default damping 0.1). Anything
else is given as its pulses (``custom``: amplitudes and times).

Timing: Klipper shifts the pulses so that their amplitude-weighted mean time is 0
(``centred``): constant-speed motion is not delayed, and the motion at t depends on the plan
up to t + |t₀| (the first pulse leads). Marlin's stepper-level ZV delays an echo of the steps
(causal, t₀ = 0). Profiles say which (``firmware.input_shaper``; default by flavour).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

#: shaper types with a closed form; ``custom`` takes its pulses as given
TYPES = ("zv", "zvd", "mzv", "ei", "custom")
#: the vibration an EI shaper leaves at its design frequency (Klipper: 1/20)
EI_VIBRATION = 0.05


@dataclass(frozen=True)
class Shaper:
    """One axis's input shaper.

    Attributes:
        type: one of :data:`TYPES`.
        freq_hz: design frequency (0 for ``custom``).
        damping_ratio: design damping ratio.
        centred: the pulses shifted to a zero amplitude-weighted mean time (Klipper).
        amplitudes, times_s: the pulses of a ``custom`` shaper (before centring); empty
            otherwise.
    """

    type: str
    freq_hz: float = 0.0
    damping_ratio: float = 0.1
    centred: bool = True
    amplitudes: tuple = ()
    times_s: tuple = ()

    @classmethod
    def from_dict(cls, d: dict) -> "Shaper":
        """From a mapping as a printer's configuration states it (``type``, ``freq_hz``,
        ``damping_ratio``, ``centred``; a custom one its ``amplitudes`` and ``times_s``)."""
        return cls(d["type"], float(d.get("freq_hz", 0.0)), float(d.get("damping_ratio", 0.1)),
                   bool(d.get("centred", True)), tuple(d.get("amplitudes", ())),
                   tuple(d.get("times_s", ())))

    def pulses(self) -> tuple[np.ndarray, np.ndarray]:
        """(a, t): amplitudes summing to 1 and times in s, ascending, as the firmware runs them
        (centred or not)."""
        if self.type == "custom":
            a, t = np.asarray(self.amplitudes, float), np.asarray(self.times_s, float)
        else:
            a, t = design_pulses(self.type, self.freq_hz, self.damping_ratio)
        a = a / a.sum()
        if self.centred:
            t = t - float(np.sum(a * t))
        return a, t

    def describe(self) -> str:
        a, t = self.pulses()
        head = (f"{self.type} {self.freq_hz:g} Hz ζ {self.damping_ratio:g}"
                if self.type != "custom" else f"custom, {a.size} pulses")
        return (f"{head}, {'centred' if self.centred else 'causal'}, "
                f"{1e3 * (t[-1] - t[0]):.1f} ms long")


def design_pulses(kind: str, freq_hz: float, damping_ratio: float):
    """(a, t) of a closed-form shaper (unnormalised amplitudes, first pulse at 0)."""
    z = float(damping_ratio)
    if not (freq_hz > 0 and 0 <= z < 1):
        raise ValueError(f"shaper {kind}: frequency {freq_hz} Hz must be > 0 and damping "
                         f"{damping_ratio} in [0, 1)")
    df = math.sqrt(1.0 - z * z)
    td = 1.0 / (freq_hz * df)           # damped period
    if kind == "zv":
        K = math.exp(-z * math.pi / df)
        return np.array([1.0, K]), np.array([0.0, 0.5 * td])
    if kind == "zvd":
        K = math.exp(-z * math.pi / df)
        return np.array([1.0, 2 * K, K * K]), np.array([0.0, 0.5 * td, td])
    if kind == "mzv":
        K = math.exp(-0.75 * z * math.pi / df)
        a1 = 1.0 - 1.0 / math.sqrt(2.0)
        return (np.array([a1, (math.sqrt(2.0) - 1.0) * K, a1 * K * K]),
                np.array([0.0, 0.375 * td, 0.75 * td]))
    if kind == "ei":
        v = EI_VIBRATION
        a1 = 0.24968 + 0.24961 * v + (0.80008 + 1.23328 * v + (0.49599 + 3.17316 * v) * z) * z
        a3 = 0.25149 + 0.21474 * v + (-0.83249 + 1.41498 * v + (0.85181 - 4.90094 * v) * z) * z
        t2 = 0.4999 + (0.46159 + 8.57843 * v) * v * z \
            + (4.26169 - 108.644 * v) * v * z * z + (1.75601 + 336.989 * v) * v * z ** 3
        return np.array([a1, 1.0 - a1 - a3, a3]), np.array([0.0, t2 * td, td])
    raise ValueError(f"unknown shaper type {kind!r}; use one of {', '.join(TYPES)}")


def residual_vibration(a, t, freq_hz, damping_ratio) -> float:
    """Vibration a mode (freq_hz, damping_ratio) keeps after the pulse train, relative to one
    unit pulse (Singer & Seering's V): 0 for a zero-vibration shaper at its design point."""
    a, t = np.asarray(a, float), np.asarray(t, float)
    wn = 2 * math.pi * float(freq_hz)
    z = float(damping_ratio)
    wd = wn * math.sqrt(1.0 - z * z)
    e = a * np.exp(z * wn * (t - t[-1]))
    return float(math.hypot(np.sum(e * np.cos(wd * t)), np.sum(e * np.sin(wd * t))) / np.sum(a))


def response(a, t, freq_hz) -> np.ndarray:
    """The shaper's frequency response Σ aᵢ e^(−j2πf tᵢ) (the factor it puts on an FRF
    measured through it)."""
    f = np.asarray(freq_hz, float)
    return np.sum(np.asarray(a)[None, :] * np.exp(-2j * np.pi * f[:, None] * np.asarray(t)[None, :]),
                  axis=1)


def reach_samples(t, ts_s: float) -> tuple[int, int]:
    """(lead, lag) in whole samples: how far ahead of and behind a sample the shaped value
    looks (lead > 0 only for centred pulses)."""
    t = np.asarray(t, float)
    lead = int(math.ceil(max(0.0, -float(t.min())) / ts_s - 1e-9))
    lag = int(math.ceil(max(0.0, float(t.max())) / ts_s - 1e-9))
    return lead, lag


def shape(u: np.ndarray, ts_s: float, a, t, *, segments=None) -> np.ndarray:
    """Σ aᵢ u(k·Ts − tᵢ) of samples u (K,) or (K, m), linear between samples; before the first
    sample the motion holds its first value and after the last its last (a plan starts and
    ends at rest; a log cut mid-motion is wrong over its last ``lead`` samples only).

    ``segments``: (starts,) of independent stretches concatenated in ``u`` (each held at its
    own ends), as the slow-down predicts several windows in one call."""
    u = np.asarray(u, float)
    K = u.shape[0]
    if K == 0:
        return u.copy()
    if segments is None:
        lo, hi = 0.0, K - 1.0
    else:  # each sample held within its own stretch
        bounds = np.append(np.asarray(segments, np.int64), K)
        seg = np.repeat(np.arange(bounds.size - 1), np.diff(bounds))
        lo, hi = bounds[:-1][seg].astype(float), bounds[1:][seg] - 1.0
    out = np.zeros_like(u)
    k = np.arange(K, dtype=float)
    for ai, ti in zip(np.asarray(a, float), np.asarray(t, float)):
        pos = np.clip(k - ti / ts_s, lo, hi)
        i0 = np.minimum(np.floor(pos).astype(np.int64), K - 1)
        i1 = np.minimum(i0 + 1, K - 1)
        fr = pos - i0
        if u.ndim == 2:
            fr = fr[:, None]
        out += ai * ((1.0 - fr) * u[i0] + fr * u[i1])
    return out


def shape_axes(pos: np.ndarray, ts_s: float, shapers: dict, *, segments=None) -> np.ndarray:
    """Positions (K, m) with column 0 (x) and 1 (y) shaped by ``shapers`` {"x"|"y": Shaper}
    (:func:`shape`); the input itself when there are none."""
    if not shapers:
        return pos
    out = np.array(pos, float, copy=True)
    for col, ax in enumerate("xy"):
        sh = shapers.get(ax)
        if sh is not None and col < out.shape[1]:
            a, t = sh.pulses()
            out[:, col] = shape(out[:, col], ts_s, a, t, segments=segments)
    return out


def reach(shapers: dict, ts_s: float) -> tuple[int, int]:
    """(lead, lag) samples of the widest of ``shapers`` ((0, 0) without any)."""
    got = [reach_samples(sh.pulses()[1], ts_s) for sh in shapers.values()]
    return (max(g[0] for g in got), max(g[1] for g in got)) if got else (0, 0)
