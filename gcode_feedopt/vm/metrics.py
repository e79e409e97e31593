"""How well a run went: cycle time, contour error, tolerance violation, prediction error.

Contour error ε_k is the XY distance from the actual position at t_k to the *commanded path
near where the machine should be*: the polyline through the commanded samples k−W .. k+W
(W = ``CONTOUR_WINDOW_S``/Ts). Locality matters on a print: the nearest point of the whole
path is often the neighbouring perimeter 0.4 mm away, which would cap every error at 0.2 mm.
The commanded samples lie on the path (firmware models follow the G-code geometry exactly and
only re-time it), so the polyline through them is the path up to the chord between two
samples: on an arc of radius R at speed v the chord lies within (v·Ts)²/(8R) of the arc, and
at a corner taken at junction speed v_j the chord cuts it by at most v_j·Ts (about 0.01 mm at
the 5 mm/s of a Klipper square corner at Ts = 2 ms).

The window counts commanded *vertices at least* ``MIN_STEP_MM`` *apart along the path* (samples
closer to the last kept one are dropped unless the direction turns there by more than
``KEEP_TURN_DEG``), not raw samples: where the command slows to a crawl or stands still, ±W raw
samples shrink to a point and the machine's ordinary lag or overshoot *along* the path would
count as contour error (measured: 0.08 mm "errors" at 0.1 mm/s on a butterfly, where the
machine was on the path). With the minimum step the window always spans at least
±W·``MIN_STEP_MM`` of path around the commanded point; above MIN_STEP_MM/Ts of speed nothing
changes.

Which samples count (``on``): ``"extrusion"`` (default) — samples inside an extruding move
(XY moving and E increasing over an adjacent sample interval), the printed contour a user
judges; travels, retractions and layer changes are left out. ``"xy"`` — every sample; what a
CNC job (no E) uses anyway: with ``"extrusion"`` and a file that never extrudes, all samples
count and ``Metrics.evaluated_on`` says ``"xy"``.

Tolerance violation (paper Sec. 5): γ_k = |ε_k| − E_max if |ε_k| > E_max else 0; its RMS is
over the evaluated samples.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from .trajectory import Trajectory

#: Half-width of the window of commanded samples searched for the contour error, s. It must
#: exceed the servo lag (a few ms of group delay plus any delay effect, ~20 ms at most) and stay
#: below the time to the next parallel line of the same print (5 mm of infill at 80 mm/s is
#: 60 ms), so that the error is measured against the line being drawn, not its neighbour.
CONTOUR_WINDOW_S = 0.05

#: Vertices of the commanded polyline closer than this along the path to the last kept one are
#: dropped (so the ±W window spans at least ±W·MIN_STEP_MM of path at any speed), mm; and a
#: vertex where the direction turns by more than KEEP_TURN_DEG is always kept (corners).
MIN_STEP_MM = 0.02
KEEP_TURN_DEG = 10.0

#: Rows per chunk in the windowed distance search (bounds memory to a few tens of MB).
_CHUNK = 1 << 18
#: Segments per chunk when thinning a polyline (a few tens of MB of temporaries).
_THIN_CHUNK = 1 << 20

#: E must grow by more than this between two samples for a move to count as extruding, mm
#: (well below one sample of the slowest extrusion, far above float round-off of E ~ 1e4 mm).
EXTRUDE_EPS_MM = 1e-7


def thin_polyline(poly_xy: np.ndarray, min_step_mm: float = MIN_STEP_MM,
                  keep_turn_deg: float = KEEP_TURN_DEG) -> tuple[np.ndarray, np.ndarray]:
    """Keep the vertices of a polyline at least ``min_step_mm`` apart along it, every vertex
    where it turns by more than ``keep_turn_deg``, and both ends.

    Returns the kept vertex indices (n,) and, for every original vertex, the index into them of
    the last kept vertex at or before it (K,)."""
    keep = _thin_mask(np.asarray(poly_xy, dtype=float), min_step_mm, keep_turn_deg)
    return np.flatnonzero(keep), np.cumsum(keep) - 1


def _thin_mask(Q: np.ndarray, min_step_mm: float, keep_turn_deg: float = KEEP_TURN_DEG,
               chunk: int = _THIN_CHUNK) -> np.ndarray:
    """(K,) bool, the vertices :func:`thin_polyline` keeps, computed ``chunk`` segments at a
    time: the optimizer thins a whole file's commanded samples (20 M on the ArcWelder
    Benchy) at every check, and whole-length temporaries took gigabytes. Bit-identical to one
    pass: the arc length is accumulated in the same order (each chunk's cumulative sum starts
    from the last one's end) and a turn is measured between consecutive moving segments
    whichever chunk they fall in."""
    K = Q.shape[0]
    if K <= 2 or min_step_mm <= 0:
        return np.ones(K, bool)
    keep = np.zeros(K, bool)
    keep[0] = keep[-1] = True
    cos_limit = np.cos(np.radians(keep_turn_deg))
    cum0 = 0.0
    last = None  # (dx, dy, length, index) of the last moving segment so far
    for c0 in range(0, K - 1, chunk):
        c1 = min(c0 + chunk, K - 1)  # segments c0 .. c1−1 (segment j joins vertex j and j+1)
        dx, dy = np.diff(Q[c0:c1 + 1, 0]), np.diff(Q[c0:c1 + 1, 1])
        seg = np.hypot(dx, dy)
        # buckets of min_step_mm along the path: a vertex in a new bucket is kept
        bucket = np.cumsum(np.concatenate([[cum0], seg]))
        cum0 = float(bucket[-1])
        np.divide(bucket, min_step_mm, out=bucket)
        np.floor(bucket, out=bucket)
        keep[c0 + 1:c1 + 1] |= bucket[1:] > bucket[:-1]
        # corners: the turn between the moves into and out of a vertex (zero moves skipped)
        mv = np.flatnonzero(seg > 0)
        mdx, mdy, mseg, at = dx[mv], dy[mv], seg[mv], mv + c0
        if last is not None:
            mdx, mdy = np.concatenate([[last[0]], mdx]), np.concatenate([[last[1]], mdy])
            mseg, at = np.concatenate([[last[2]], mseg]), np.concatenate([[last[3]], at])
        if mdx.size > 1:
            cos = (mdx[:-1] * mdx[1:] + mdy[:-1] * mdy[1:]) / (mseg[:-1] * mseg[1:])
            keep[at[1:][cos < cos_limit]] = True  # the vertex where the outgoing move starts
        if mdx.size:
            last = (mdx[-1], mdy[-1], mseg[-1], at[-1])
    return keep


def distance_to_polyline_window(points_xy: np.ndarray, poly_xy: np.ndarray, window: int,
                                index: np.ndarray | None = None,
                                min_step_mm: float = MIN_STEP_MM) -> np.ndarray:
    """XY distance from each point to the polyline through ``poly_xy`` near its own index.

    Args:
        points_xy: shape (M, 2). Points, mm.
        poly_xy: shape (K, 2). Polyline vertices (the commanded samples), mm.
        window: W; point m is compared with the segments between the W thinned vertices
            (:func:`thin_polyline`) before and after its own (clipped to the polyline).
        index: shape (M,) int, vertex index of each point (default ``arange(M)``, M = K).
        min_step_mm: the thinning's minimum step (0: every vertex, a window of ±W samples).

    Returns:
        shape (M,). Distances, mm (0 where a point lies on the polyline).
    """
    P = np.asarray(points_xy, dtype=float)
    Q = np.asarray(poly_xy, dtype=float)
    kept = np.flatnonzero(_thin_mask(Q, min_step_mm))
    idx = np.arange(P.shape[0]) if index is None else np.asarray(index, dtype=np.int64)
    idx = np.searchsorted(kept, idx, side="right") - 1  # the last kept vertex at or before
    Q = Q[kept]
    M, K = P.shape[0], Q.shape[0]
    if K == 1:
        return np.hypot(P[:, 0] - Q[0, 0], P[:, 1] - Q[0, 1])
    # segment j joins vertex j and j+1, j in 0..K-2
    A = Q[:-1]
    D = Q[1:] - Q[:-1]
    L2 = np.einsum("ij,ij->i", D, D)
    inv = np.divide(1.0, L2, out=np.zeros_like(L2), where=L2 > 0)
    best = np.empty(M)
    for c0 in range(0, M, _CHUNK):
        c1 = min(c0 + _CHUNK, M)
        px, py = P[c0:c1, 0], P[c0:c1, 1]
        ic = idx[c0:c1]
        b = np.full(c1 - c0, np.inf)
        for off in range(-window, window):
            j = np.clip(ic + off, 0, K - 2)
            ax, ay = A[j, 0], A[j, 1]
            dx, dy = D[j, 0], D[j, 1]
            rx, ry = px - ax, py - ay
            u = np.clip((rx * dx + ry * dy) * inv[j], 0.0, 1.0)
            ex, ey = rx - u * dx, ry - u * dy
            np.minimum(b, ex * ex + ey * ey, out=b)
        best[c0:c1] = np.sqrt(b)
    return best


def contour_error_mm(commanded_mm: np.ndarray, actual_mm: np.ndarray, ts_s: float,
                     window_s: float = CONTOUR_WINDOW_S) -> np.ndarray:
    """Shape (K,). Unsigned XY contour error of every sample, mm (see the module docstring)."""
    W = max(1, int(round(window_s / ts_s)))
    return distance_to_polyline_window(np.asarray(actual_mm)[:, :2], np.asarray(commanded_mm)[:, :2], W)


def extrusion_mask(trajectory: Trajectory) -> np.ndarray:
    """Shape (K,) bool. Samples inside an extruding XY move: the XY position and E both advance
    over the interval before or after the sample (and, where the trajectory knows its moves,
    one end of that interval lies in an extruding XY move: a travel that stops within the
    same Ts as an E-only prime starts is not extruding)."""
    pos, e = trajectory.pos_mm, trajectory.e_mm
    K = pos.shape[0]
    step = (np.any(np.diff(pos[:, :2], axis=0) != 0, axis=1)
            & (np.diff(e) > EXTRUDE_EPS_MM))
    blk = getattr(trajectory, "in_extrusion", None)
    if blk is not None:
        step &= blk[:-1] | blk[1:]
    mask = np.zeros(K, dtype=bool)
    mask[:-1] |= step
    mask[1:] |= step
    return mask


def tolerance_violation_mm(contour_error: np.ndarray, tol_mm: float) -> np.ndarray:
    """γ = |ε| − E_max where |ε| > E_max, else 0 (paper Sec. 5), same shape as ε."""
    return np.maximum(np.abs(contour_error) - tol_mm, 0.0)


def rms(a: np.ndarray) -> float:
    a = np.asarray(a, dtype=float)
    return float(np.sqrt(np.mean(a * a))) if a.size else 0.0


def prediction_rms_mm(actual_mm: np.ndarray, predicted_mm: np.ndarray) -> dict[str, float]:
    """{"x": .., "y": ..}: RMS of actual − predicted per axis, mm. Arrays (K, ≥2)."""
    a, p = np.asarray(actual_mm), np.asarray(predicted_mm)
    if a.shape[0] != p.shape[0]:
        raise ValueError(f"prediction has {p.shape[0]} samples, actual {a.shape[0]}")
    return {ax: rms(a[:, i] - p[:, i]) for i, ax in enumerate(("x", "y"))}


@dataclass(frozen=True)
class Metrics:
    """Figures of one run. Lengths in mm, times in s.

    ``within_fraction`` is the fraction of evaluated samples with |ε| ≤ E_max (compare with the
    stringency η); ``p95_contour_error_mm`` the 95th percentile of ε (linear interpolation);
    ``prediction_rms_mm`` is {} when no prediction was given.
    """

    cycle_time_s: float
    tol_mm: float
    n_samples: int
    n_evaluated: int
    evaluated_on: str
    rms_gamma_mm: float
    max_gamma_mm: float
    within_fraction: float
    rms_contour_error_mm: float
    max_contour_error_mm: float
    p95_contour_error_mm: float = 0.0
    prediction_rms_mm: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return asdict(self)

    def summary(self) -> str:
        """A few human lines."""
        lines = [
            f"cycle time        {self.cycle_time_s:12.3f} s",
            f"contour error     RMS {self.rms_contour_error_mm:.4f} mm, 95 % {self.p95_contour_error_mm:.4f} mm, "
            f"max {self.max_contour_error_mm:.4f} mm "
            f"({self.evaluated_on} samples: {self.n_evaluated} of {self.n_samples})",
            f"within {self.tol_mm:g} mm     {100 * self.within_fraction:8.3f} % of samples",
            f"violation gamma   RMS {self.rms_gamma_mm:.5f} mm, max {self.max_gamma_mm:.4f} mm",
        ]
        if self.prediction_rms_mm:
            lines.append("prediction RMS    " + ", ".join(f"{k} {v:.5f} mm" for k, v in self.prediction_rms_mm.items()))
        return "\n".join(lines)


def evaluate(trajectory: Trajectory, actual_mm: np.ndarray, tol_mm: float, *,
             predicted_mm: np.ndarray | None = None, on: str = "extrusion",
             window_s: float = CONTOUR_WINDOW_S) -> Metrics:
    """Metrics of a run: commanded ``trajectory`` and the plant's ``actual_mm`` (K, 3).

    ``on`` is ``"extrusion"`` or ``"xy"`` (see the module docstring); ``predicted_mm`` (K, ≥2)
    adds the prediction RMS per axis (over all samples).
    """
    actual = np.asarray(actual_mm, dtype=float)
    if actual.shape != trajectory.pos_mm.shape:
        raise ValueError(f"actual_mm has shape {actual.shape}, the trajectory {trajectory.pos_mm.shape}")
    if on not in ("extrusion", "xy"):
        raise ValueError(f"on={on!r}: use 'extrusion' or 'xy'")
    K = trajectory.n_samples
    mask = extrusion_mask(trajectory) if on == "extrusion" else np.ones(K, dtype=bool)
    if on == "extrusion" and not mask.any():
        mask, on = np.ones(K, dtype=bool), "xy"
    W = max(1, int(round(window_s / trajectory.ts_s)))
    idx = np.flatnonzero(mask)
    eps = distance_to_polyline_window(actual[idx, :2], trajectory.pos_mm[:, :2], W, index=idx)
    gamma = tolerance_violation_mm(eps, tol_mm)
    return Metrics(
        cycle_time_s=trajectory.duration_s,
        tol_mm=float(tol_mm),
        n_samples=K,
        n_evaluated=int(idx.size),
        evaluated_on=on,
        rms_gamma_mm=rms(gamma),
        max_gamma_mm=float(gamma.max()) if gamma.size else 0.0,
        within_fraction=float(np.mean(eps <= tol_mm)) if eps.size else 1.0,
        rms_contour_error_mm=rms(eps),
        max_contour_error_mm=float(eps.max()) if eps.size else 0.0,
        p95_contour_error_mm=float(np.quantile(eps, 0.95)) if eps.size else 0.0,
        prediction_rms_mm=prediction_rms_mm(actual, predicted_mm) if predicted_mm is not None else {},
    )
