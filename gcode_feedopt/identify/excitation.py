"""Commanded acceleration of Klipper's legacy resonance test (pure numerics).

Legacy (v0.12 and earlier) defaults: A = 75 mm/s² per Hz, f from 5 to 133.33 Hz rising at
H = 1 Hz/s; the commanded acceleration is a ±A·f square wave of period 1/f whose frequency
rises linearly, f(t) = f0 + H·t (../shared/data/PROVENANCE.md). Only this generator is
implemented; the current (v0.13+) one is not.
"""

from __future__ import annotations

import numpy as np

LEGACY = {"accel_per_hz": 75.0, "freq_start_hz": 5.0, "freq_end_hz": 133.33, "hz_per_sec": 1.0}


def legacy_accel_mm_s2(fs_hz: float, accel_per_hz: float = 75.0, freq_start_hz: float = 5.0,
                       freq_end_hz: float = 133.33, hz_per_sec: float = 1.0):
    """(t_s (K,), accel_mm_s2 (K,)) sampled at ``fs_hz``."""
    duration_s = (freq_end_hz - freq_start_hz) / hz_per_sec
    t_s = np.arange(0.0, duration_s, 1.0 / fs_hz)
    f_hz = freq_start_hz + hz_per_sec * t_s
    phase = freq_start_hz * t_s + 0.5 * hz_per_sec * t_s**2  # cycles
    return t_s, accel_per_hz * f_hz * np.sign(np.sin(2 * np.pi * phase) + 1e-12)
