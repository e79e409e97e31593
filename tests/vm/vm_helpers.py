"""Closed forms shared by the plant and effect tests (a uniquely named module: tests/ has no
__init__.py, so pytest puts this folder on sys.path)."""

from __future__ import annotations

import numpy as np

TS = 0.002


def second_order_step(t, wn, zeta):
    """Unit step response of wn^2 / (s^2 + 2 zeta wn s + wn^2), t >= 0."""
    wd = wn * np.sqrt(1 - zeta**2)
    return 1 - np.exp(-zeta * wn * t) * (np.cos(wd * t) + zeta * wn / wd * np.sin(wd * t))


def step_invariant_impulse(wn, zeta, n, ts_s=TS):
    """h[k] = y(kTs) - y((k-1)Ts): the discrete response to a sampled step equals y(kTs)."""
    y = second_order_step(np.arange(n) * ts_s, wn, zeta)
    return np.diff(np.concatenate(([0.0], y)))
