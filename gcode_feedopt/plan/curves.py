"""Smooth reference curves: a rational B-spline (NURBS) as published with a contouring
benchmark (``degree``, ``control_points_mm``, ``weights``, ``knots``; e.g. the butterfly of
../shared/data/butterfly_nurbs.json). Used to write the sample butterfly G-code and for the
time-optimal bound of the contour (plan.bound)."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import BSpline


def nurbs_curve(data: dict):
    """(curve, u0, u1): ``curve(u)`` → (len(u), d) points of the NURBS for parameters in
    [u0, u1]."""
    p = data["degree"]
    cp = np.asarray(data["control_points_mm"], float)
    w = np.asarray(data["weights"], float)
    t = np.asarray(data["knots"], float)
    num = BSpline(t, cp * w[:, None], p)
    den = BSpline(t, w, p)
    return (lambda u: num(u) / den(u)[:, None]), t[p], t[-p - 1]


def nurbs_points(data: dict, n: int = 200001) -> np.ndarray:
    """(n, 2) XY points of the NURBS at n evenly spaced parameters."""
    curve, u0, u1 = nurbs_curve(data)
    return curve(np.linspace(u0, u1, n))[:, :2]
