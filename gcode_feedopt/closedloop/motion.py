"""Seeded point-to-point XY motions for hiding effects in virtual-machine logs (tests, demos).

Each move goes in a straight line to a random target in the box with a quintic (minimum-jerk)
time law x = x0 + D(10τ³ − 15τ⁴ + 6τ⁵), its duration set by the speed and acceleration limits
(peak speed 1.875 D/T, peak acceleration 5.77 D/T²), followed by a random dwell: the log has
reversals, rests, a range of speeds and positions across the box.
"""

from __future__ import annotations

import numpy as np


def point_to_point(rng: np.random.Generator, *, duration_s: float = 20.0, ts_s: float = 0.002,
                   box_mm=(20.0, 200.0), speed_mm_s=(30.0, 150.0), accel_mm_s2: float = 3000.0,
                   dwell_s=(0.0, 0.2)) -> np.ndarray:
    """Shape (K, 3) commanded X, Y, Z (Z = 0), K = duration_s / ts_s."""
    K = int(round(duration_s / ts_s))
    out = np.empty((K, 3))
    out[:, 2] = 0.0
    pos = rng.uniform(*box_mm, size=2)
    k = 0
    while k < K:
        target = rng.uniform(*box_mm, size=2)
        D = float(np.linalg.norm(target - pos))
        v = rng.uniform(*speed_mm_s)
        T = max(1.875 * D / v, np.sqrt(5.77 * D / accel_mm_s2), 2 * ts_s)
        n = int(np.ceil(T / ts_s))
        tau = np.arange(1, n + 1) / n
        s = 10 * tau ** 3 - 15 * tau ** 4 + 6 * tau ** 5
        seg = pos + s[:, None] * (target - pos)
        nd = int(rng.uniform(*dwell_s) / ts_s)
        seg = np.vstack([seg, np.repeat(target[None], nd, axis=0)])
        m = min(seg.shape[0], K - k)
        out[k:k + m, :2] = seg[:m]
        k += m
        pos = target
    return out
