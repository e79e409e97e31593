"""Synthetic geometry (circle, line) and dynamics (a 2nd-order mode) for the optimizer tests."""

from __future__ import annotations

import numpy as np


class Circle:
    """Circle of radius r_mm about the origin, starting at (r, 0), CCW, parametrised by s."""

    def __init__(self, r_mm: float):
        self.r = float(r_mm)
        self.total_length_mm = 2 * np.pi * self.r

    def position(self, s):
        th = np.asarray(s, float) / self.r
        return np.column_stack([self.r * np.cos(th), self.r * np.sin(th), 0 * th])

    def tangent(self, s):
        th = np.asarray(s, float) / self.r
        return np.column_stack([-np.sin(th), np.cos(th), 0 * th])


class Line:
    """Straight line from the origin along the unit direction u (3,)."""

    def __init__(self, u, length_mm: float):
        self.u = np.asarray(u, float) / np.linalg.norm(u)
        self.total_length_mm = float(length_mm)

    def position(self, s):
        return np.asarray(s, float)[:, None] * self.u[None, :]

    def tangent(self, s):
        return np.repeat(self.u[None, :], np.asarray(s).size, axis=0)


def second_order_impulse(f_hz: float, zeta: float, ts_s: float, n: int = 400) -> np.ndarray:
    """Impulse response (per Ts sample, unit DC gain) of a unit-gain 2nd-order mode, as the
    first difference of its exact step response."""
    w = 2 * np.pi * f_hz
    wd = w * np.sqrt(1 - zeta ** 2)
    t = np.arange(n) * ts_s
    step = 1 - np.exp(-zeta * w * t) * (np.cos(wd * t) + zeta * w / wd * np.sin(wd * t))
    h = np.diff(np.concatenate([[0.0], step]))
    return h / h.sum()


def fir_response(cmd_xy: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Actual XY of a commanded XY (K, 2) through h on both axes (x_0 held at rest)."""
    x0 = cmd_xy[0]
    out = np.empty_like(cmd_xy)
    for a in range(2):
        out[:, a] = x0[a] + np.convolve(cmd_xy[:, a] - x0[a], h)[: cmd_xy.shape[0]]
    return out
