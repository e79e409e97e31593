"""Commanded acceleration of Klipper's resonance test, legacy and current generator (pure numerics).

Rebuilt from the move sequence of Klipper's ``klippy/extras/resonance_tester.py`` (read, not
copied). Both generators step the frequency once per half period: with ``t_k = 1/(4 f_k)``,
``a_k = accel_per_hz * f_k`` and ``f_{k+1} = f_k + 2 t_k * hz_per_sec`` (so f rises at
``hz_per_sec`` on average), while ``f_k <= freq_end``.

- **legacy** (v0.12 and earlier, ``VibrationPulseTest.run_test``): for each f_k the toolhead
  moves out by ``L_k = a_k t_k^2 / 2`` (alternating side) and back, at accel a_k with
  ``max_v = a_k t_k = accel_per_hz/4``. A reversal forces a stop, but a "back" move and the
  next "out" move are collinear, so the planner runs through the centre at ``accel_per_hz/4``:
  back_k accelerates for t_k, out_{k+1} decelerates for t_{k+1}. Commanded acceleration: a
  short triangle ``+a_0, -a_0`` (``t_0/sqrt 2`` each: out_0 starts and ends at rest), then
  ``-a_0 (t_0), +a_1, +a_1, -a_2, -a_2, ...`` and a final stop triangle. Defaults
  A = 75 mm/s^2/Hz, 5 to 10000/75 = 133.33 Hz, 1 Hz/s.
- **current** (v0.13+, ``VibrationPulseTestGenerator`` + ``SweepingVibrationsTestGenerator``):
  constant-acceleration pieces ``+s a_k`` then ``-s a_k`` of t_k each, s flipping every k,
  plus a slow "sweeping" square wave ``± sweeping_accel`` whose first switch comes after
  ``period * sqrt(2)/8``, the next after ``period * (sqrt(2)/8 + 1/4)``, then every
  ``period/2``. Defaults A = 60 mm/s^2/Hz, 5 to 135 Hz, 1 Hz/s, 400 mm/s^2, 1.2 s.

Both are square waves of instantaneous frequency f(t) in cosine phase (acceleration at its
extreme when the toolhead is at rest), amplitude A*f.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import signal

from ..errors import ProfileError


@dataclass(frozen=True)
class Excitation:
    """Parameters of one Klipper resonance test (``generator``: 'legacy' | 'current')."""

    generator: str
    accel_per_hz: float
    freq_start_hz: float
    freq_end_hz: float
    hz_per_sec: float
    sweeping_accel_mm_s2: float = 0.0
    sweeping_period_s: float = 0.0

    def with_overrides(self, **kw) -> "Excitation":
        """Copy with every keyword that is not None replaced."""
        return replace(self, **{k: v for k, v in kw.items() if v is not None})

    def to_dict(self) -> dict:
        return {k: (round(v, 6) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


LEGACY = Excitation("legacy", 75.0, 5.0, 10000.0 / 75.0, 1.0)
CURRENT = Excitation("current", 60.0, 5.0, 135.0, 1.0, 400.0, 1.2)
GENERATORS = {"legacy": LEGACY, "current": CURRENT}


def _vibration_pieces(ex: Excitation):
    """(duration_s (P,), accel (P,)) of the current generator's vibration part."""
    if not (ex.freq_start_hz > 0 and ex.freq_end_hz >= ex.freq_start_hz and ex.hz_per_sec > 0
            and ex.accel_per_hz > 0):
        raise ProfileError(f"excitation: need 0 < freq_start <= freq_end, hz_per_sec > 0 and "
                           f"accel_per_hz > 0, got {ex.to_dict()}; fix the --freq-*/--hz-per-sec/"
                           f"--accel-per-hz options")
    dur, acc = [], []
    f, sign = ex.freq_start_hz, 1.0
    while f <= ex.freq_end_hz + 1e-6:
        t_seg = 0.25 / f
        a = ex.accel_per_hz * f
        dur += [t_seg, t_seg]
        acc += [sign * a, -sign * a]
        f += 2.0 * t_seg * ex.hz_per_sec
        sign = -sign
    return np.array(dur), np.array(acc)


def _legacy_pieces(ex: Excitation):
    dur_v, acc_v = _vibration_pieces(ex)
    t = dur_v[0::2]                       # t_k, one per frequency step
    a = np.abs(acc_v[0::2])               # a_k
    n = len(t)
    dur, acc = [t[0] / math.sqrt(2)] * 2, [a[0], -a[0]]   # out_0: rest to rest
    side = 1.0                            # side of the last "out" move
    for k in range(n - 1):
        # back_k towards the centre (accelerating), out_{k+1} to the other side (decelerating)
        dur += [t[k], t[k + 1]]
        acc += [-side * a[k], side * a[k + 1]]
        side = -side
    dur += [t[-1] / math.sqrt(2)] * 2     # last back move: rest to rest
    acc += [-side * a[-1], side * a[-1]]
    return np.array(dur), np.array(acc)


def _add_sweeping(ex: Excitation, dur, acc):
    if not ex.sweeping_period_s or not ex.sweeping_accel_mm_s2:
        return dur, acc
    edges = np.r_[0.0, np.cumsum(dur)]
    frac = math.sqrt(2.0) * 0.125
    switches, t = [], ex.sweeping_period_s * frac
    frac += 0.25
    while t < edges[-1]:
        switches.append(t)
        t += ex.sweeping_period_s * frac
        frac = 0.5
    new_edges = np.union1d(edges, switches)
    mid = 0.5 * (new_edges[1:] + new_edges[:-1])
    base = acc[np.clip(np.searchsorted(edges, mid, side="right") - 1, 0, len(acc) - 1)]
    sig = np.where(np.searchsorted(np.array(switches), mid) % 2 == 0, 1.0, -1.0)
    return np.diff(new_edges), base + ex.sweeping_accel_mm_s2 * sig


def pieces(ex: Excitation):
    """(t_edges_s (P+1,), accel_mm_s2 (P,)): piecewise-constant commanded acceleration."""
    if ex.generator == "legacy":
        dur, acc = _legacy_pieces(ex)
    elif ex.generator == "current":
        dur, acc = _add_sweeping(ex, *_vibration_pieces(ex))
    else:
        raise ProfileError(f"excitation: unknown generator {ex.generator!r}; use legacy or current")
    return np.r_[0.0, np.cumsum(dur)], acc


def duration_s(ex: Excitation) -> float:
    return float(pieces(ex)[0][-1])


def freq_at(ex: Excitation):
    """Function t_c (s from the start of the test) -> swept frequency, Hz (NaN outside it)."""
    dur = duration_s(ex)

    def f(t_c):
        t_c = np.asarray(t_c, float)
        fr = np.clip(ex.freq_start_hz + ex.hz_per_sec * t_c, ex.freq_start_hz, ex.freq_end_hz)
        return np.where((t_c >= 0) & (t_c <= dur), fr, np.nan)
    return f


def sampled_accel(ex: Excitation, fs_hz: float, oversample: int = 8, pad_s: float = 0.0):
    """Band-limited commanded acceleration sampled at ``fs_hz`` -> (t_s (K,), accel (K,)).

    The velocity of a piecewise-constant acceleration is exact at any instant; its finite
    difference at ``oversample * fs_hz`` is the acceleration averaged over each fine sample,
    which is then low-passed and decimated (zero phase), so the square wave's harmonics above
    the Nyquist frequency do not alias into the band. ``pad_s`` of rest is added at both ends.
    """
    edges, acc = pieces(ex)
    vel_edges = np.r_[0.0, np.cumsum(acc * np.diff(edges))]
    fs_hi = fs_hz * oversample
    t_hi = np.arange(-pad_s, edges[-1] + pad_s + 2.0 / fs_hz, 1.0 / fs_hi)
    v = np.interp(t_hi, edges, vel_edges)             # exact: velocity is piecewise linear
    a_hi = np.diff(v) * fs_hi                         # mean accel over [t_i, t_i+1]
    a = signal.decimate(a_hi, oversample, ftype="fir", zero_phase=True)
    t = t_hi[:-1:oversample][:len(a)] + 0.5 / fs_hi
    return t, a


def legacy_accel_mm_s2(fs_hz: float, accel_per_hz: float = 75.0, freq_start_hz: float = 5.0,
                       freq_end_hz: float = 10000.0 / 75.0, hz_per_sec: float = 1.0):
    """Legacy generator sampled at ``fs_hz`` -> (t_s (K,), accel_mm_s2 (K,)) (no padding)."""
    ex = Excitation("legacy", accel_per_hz, freq_start_hz, freq_end_hz, hz_per_sec)
    return sampled_accel(ex, fs_hz)
