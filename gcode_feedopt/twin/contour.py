"""Contour error: the twin's predictive distribution (paper Eqs. 6 and 21, both signs) and the
true geometric error (distance to the nearest point of the path) for evaluation."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


def inclination(xd: np.ndarray, yd: np.ndarray) -> np.ndarray:
    """θ(t), the direction of travel of the desired curve (finite differences; held through
    standstills), rad."""
    dx = np.gradient(xd)
    dy = np.gradient(yd)
    th = np.arctan2(dy, dx)
    moving = np.hypot(dx, dy) > 1e-12
    if moving.any():
        idx = np.where(moving, np.arange(th.size), 0)
        np.maximum.accumulate(idx, out=idx)
        th = th[idx]
    return th


def contour_distribution(xd, yd, mx, sx, my, sy):
    """Mean and std of the linearised contour error ε = −sinθ·(x_d − x̃) + cosθ·(y_d − ỹ)
    (Eq. 6, with the sign that makes ε the signed normal distance; Eq. 21 for its variance,
    axes independent)."""
    th = inclination(xd, yd)
    s, c = np.sin(th), np.cos(th)
    mean = -s * (xd - mx) + c * (yd - my)
    std = np.sqrt((s * sx) ** 2 + (c * sy) ** 2)
    return mean, std


def chance_bounds(mean, std, eta: float):
    """The worst case of η of the contour-error distribution on each side:
    μ + Φ⁻¹(η)σ and μ − Φ⁻¹(η)σ (paper Eq. 27, both signs)."""
    from scipy.stats import norm

    z = float(norm.ppf(eta))
    return mean + z * std, mean - z * std


def geometric_contour_error(path_xy: np.ndarray, points_xy: np.ndarray) -> np.ndarray:
    """Distance from each point (M, 2) to the nearest point of the polyline path_xy (P, 2), mm.

    A KD-tree over the vertices finds candidate segments; the exact point-to-segment distance
    is taken over the segments adjacent to the k nearest vertices (k = 8), which is exact
    whenever the nearest segment has one of those vertices as an end — true for paths sampled
    finer than the distances asked for."""
    P = np.asarray(path_xy, float)
    Q = np.asarray(points_xy, float)
    tree = cKDTree(P)
    k = min(8, len(P))
    _, idx = tree.query(Q, k=k)
    idx = np.atleast_2d(idx.T).T if k > 1 else idx[:, None]
    best = np.full(len(Q), np.inf)
    for j in range(idx.shape[1]):
        for off in (-1, 0):
            a_i = np.clip(idx[:, j] + off, 0, len(P) - 2)
            a, b = P[a_i], P[a_i + 1]
            ab = b - a
            L2 = np.einsum("ij,ij->i", ab, ab)
            u = np.clip(np.einsum("ij,ij->i", Q - a, ab) / np.where(L2 > 0, L2, 1.0), 0, 1)
            d = np.linalg.norm(Q - (a + ab * u[:, None]), axis=1)
            best = np.minimum(best, d)
    return best
