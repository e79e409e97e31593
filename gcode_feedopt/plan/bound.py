"""The shortest time in which any planner can traverse a smooth curve under the kinematic limits
alone: feed ≤ V, and per-axis acceleration ≤ A (or the acceleration vector's norm ≤ A).

This is the yardstick for a cycle-time comparison: no method obeying V and A — whatever it
knows about the machine's dynamics — can be faster, so ``(T_method − T_bound)/T_method`` is the
most any better method could win over it. It is computed independently of the planners (no
junction rule, no sample grid in time), by the classic phase-plane method on u = ṡ²:

- along the arc length s with unit tangent p′ and curvature vector p″, the axis acceleration is
  a_i = p′_i s̈ + p″_i u, with s̈ = ½ du/ds;
- the velocity-limit curve caps u by V² and by the centripetal part, |p″_i| u ≤ A (per axis) or
  |p″| u ≤ A (norm);
- a forward pass raises u as fast as the largest admissible s̈ allows, a backward pass lowers it
  as the most negative one allows (rest at both ends), each step using the limits at its own
  start; the minimum of the two is the time-optimal speed profile (Bobrow 1985; Shin & McKay
  1985), to O(ds).

Curvature is taken from the points by finite differences, so the points must sample a smooth
curve finely (a polyline with corners has no finite bound: it must stop at each corner).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TimeBound:
    time_s: float
    length_mm: float
    s_mm: np.ndarray       # (N,) arc length of the grid
    speed_mm_s: np.ndarray  # (N,) time-optimal speed on it

    @property
    def mean_speed_mm_s(self) -> float:
        return self.length_mm / self.time_s if self.time_s > 0 else 0.0


def resample_by_arc_length(points_mm: np.ndarray, ds_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, d) re-sampled every ``ds_mm`` of arc length (linear between the given points,
    the last point kept): returns (s (M,), points (M, d))."""
    P = np.asarray(points_mm, dtype=float)
    seg = np.linalg.norm(np.diff(P, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    grid = np.arange(0.0, s[-1], ds_mm)
    if s[-1] - grid[-1] < 0.5 * ds_mm and grid.size > 1:
        grid = grid[:-1]
    grid = np.append(grid, s[-1])
    return grid, np.column_stack([np.interp(grid, s, P[:, i]) for i in range(P.shape[1])])


def time_optimal_bound(points_mm: np.ndarray, vmax_mm_s: float, amax_mm_s2: float, *,
                       per_axis: bool = True, ds_mm: float = 0.01) -> TimeBound:
    """Time-optimal rest-to-rest traversal of the curve through ``points_mm`` (N, 2 or 3),
    feed ≤ ``vmax_mm_s``, acceleration ≤ ``amax_mm_s2`` per axis (``per_axis``) or in norm."""
    if vmax_mm_s <= 0 or amax_mm_s2 <= 0:
        raise ValueError("vmax_mm_s and amax_mm_s2 must be positive")
    s, q = resample_by_arc_length(points_mm, ds_mm)
    n = s.size
    if n < 3:
        raise ValueError("need a curve of at least two grid steps")
    t1 = np.gradient(q, s, axis=0)
    t1 /= np.linalg.norm(t1, axis=1)[:, None]
    t2 = np.gradient(t1, s, axis=0)
    A = float(amax_mm_s2)
    kap = np.abs(t2) if per_axis else np.linalg.norm(t2, axis=1)[:, None]
    with np.errstate(divide="ignore"):
        ulim = np.min(np.where(kap > 0, A / kap, np.inf), axis=1)
    ulim = np.minimum(ulim, float(vmax_mm_s) ** 2)
    ulim[0] = ulim[-1] = 0.0

    def sddot_range(k: int, u: float) -> tuple[float, float]:
        if not per_axis:
            r = A * A - (kap[k, 0] * u) ** 2
            r = np.sqrt(r) if r > 0 else 0.0
            return -r, r
        lo, hi = -np.inf, np.inf
        for i in range(t1.shape[1]):
            a1, a2 = t1[k, i], t2[k, i] * u
            if abs(a1) < 1e-12:
                continue
            b1, b2 = (-A - a2) / a1, (A - a2) / a1
            lo, hi = max(lo, min(b1, b2)), min(hi, max(b1, b2))
        return lo, hi

    ds = np.diff(s)
    u = ulim.tolist()
    for k in range(n - 1):
        hi = max(sddot_range(k, u[k])[1], 0.0)
        u[k + 1] = min(u[k + 1], u[k] + 2.0 * ds[k] * hi)
    for k in range(n - 1, 0, -1):
        lo = min(sddot_range(k, u[k])[0], 0.0)
        u[k - 1] = min(u[k - 1], u[k] - 2.0 * ds[k - 1] * lo)
    v = np.sqrt(np.maximum(np.asarray(u), 0.0))
    t = float(np.sum(2.0 * ds / np.maximum(v[1:] + v[:-1], 1e-12)))
    return TimeBound(time_s=t, length_mm=float(s[-1]), s_mm=s, speed_mm_s=v)
