"""Look-ahead trapezoid planning over a chain of segments, and exact sampling at Ts.

The pure numerical core shared by the kinematic planner (and usable by firmware models):

1. :func:`junction_speeds` — the highest speed at each junction allowed by the junction rule
   (junction deviation, as Marlin 2 and Klipper both use), by the neighbours' speed caps and
   by exact stops;
2. :func:`forward_backward` — the classic two-pass look-ahead so every segment can reach its
   exit speed from its entry speed within its acceleration;
3. :func:`trapezoids` — per-segment accelerate / cruise / decelerate phases;
4. :func:`sample` — the path coordinate s(t) at t = k·Ts, vectorized (searchsorted over the
   phase boundaries), exact to round-off at every sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Below this |cos| distance from a reversal the junction counts as a full reversal (stop).
REVERSAL_COS = 0.999999
#: Straight-on junctions (cos of the turn above this) impose no junction limit.
STRAIGHT_COS = 0.999999


def junction_speeds(turn_cos: np.ndarray, accel_mm_s2: np.ndarray, deviation_mm: float,
                    vcap_mm_s: np.ndarray, stop_after: np.ndarray,
                    centripetal_len_mm: np.ndarray | None = None) -> np.ndarray:
    """Highest speed at each of the N-1 inner junctions and the two ends, mm/s.

    Args:
        turn_cos: (N-1,) cosine of the angle between the outgoing tangent of segment i and
            the incoming tangent of segment i+1 (1 = straight on, -1 = reversal).
        accel_mm_s2: (N,) acceleration available on each segment.
        deviation_mm: junction deviation δ: v² = a·δ·sin(θ/2)/(1 − sin(θ/2)), with θ the
            angle between the reversed incoming and the outgoing direction (Marlin 2's rule;
            Klipper's square_corner_velocity maps to δ = scv²(√2 − 1)/a).
        vcap_mm_s: (N,) speed cap of each segment.
        stop_after: (N,) exact stop at the end of segment i.
        centripetal_len_mm: (N,) if given, Klipper's extra limit v² ≤ ½·L·a·tan(θ/2) with the
            length of each neighbouring segment (a corner made of short segments is an arc).

    Returns:
        (N+1,) speed limit at the boundaries; entries 0 and N are 0 (start and end at rest).
    """
    n = vcap_mm_s.size
    vj = np.zeros(n + 1)
    if n == 0:
        return vj
    c = np.clip(turn_cos, -1.0, 1.0)
    # θ as Marlin defines it: angle between -u_in and u_out, so cos θ = -turn_cos
    cos_theta = -c
    sin_d2 = np.sqrt(np.maximum(0.5 * (1.0 - cos_theta), 0.0))
    a_j = np.minimum(accel_mm_s2[:-1], accel_mm_s2[1:])
    with np.errstate(divide="ignore", invalid="ignore"):
        v2 = a_j * deviation_mm * sin_d2 / (1.0 - sin_d2)
        if centripetal_len_mm is not None:
            cos_d2 = np.sqrt(np.maximum(0.5 * (1.0 + cos_theta), 0.0))
            tan_d2 = sin_d2 / cos_d2
            cen = 0.5 * tan_d2 * np.minimum(centripetal_len_mm[:-1] * accel_mm_s2[:-1],
                                           centripetal_len_mm[1:] * accel_mm_s2[1:])
            v2 = np.minimum(v2, cen)
    v2 = np.where(c >= STRAIGHT_COS, np.inf, v2)
    v2 = np.where(c <= -REVERSAL_COS, 0.0, v2)
    v = np.sqrt(np.maximum(v2, 0.0))
    v = np.minimum(v, np.minimum(vcap_mm_s[:-1], vcap_mm_s[1:]))
    v = np.where(stop_after[:-1], 0.0, v)
    vj[1:n] = v
    return vj


#: Marlin's JD_HANDLE_SMALL_SEGMENTS (on by default since Marlin 2.0): an outgoing block
#: shorter than this (mm) whose junction turns by less than 45° is treated as an arc.
SMALL_SEGMENT_MM = 1.0
SMALL_SEGMENT_COS = 0.7071067812
#: the floor of Marlin's polynomial acos in that rule (planner.cpp: "bottoms out at 0.033")
SMALL_SEGMENT_MIN_RAD = 0.0329


def small_segment_limits(turn_cos: np.ndarray, accel_mm_s2: np.ndarray,
                         length_mm: np.ndarray) -> np.ndarray:
    """(N-1,) Marlin 2's small-segment junction limit v² ≤ L·a/θ (planner.cpp,
    JD_HANDLE_SMALL_SEGMENTS): for an outgoing block of length L < 1 mm turning by θ < 45° the
    junction is an arc of radius L/θ, so the centripetal acceleration stays a. Without it a
    curve drawn with 0.03 mm segments at 14° each passes junction deviation at 72 mm/s — a
    0.12 mm radius at 9.8 m/s²; with it, 19 mm/s."""
    c = np.clip(turn_cos, -1.0, 1.0)
    # Marlin evaluates acos with a polynomial whose value bottoms out at 0.033 rad, so even
    # collinear short blocks are limited (a 0.03 mm block to 52 mm/s at 3000 mm/s²)
    theta = np.maximum(np.arccos(c), SMALL_SEGMENT_MIN_RAD)
    L = length_mm[1:]
    a = np.minimum(accel_mm_s2[:-1], accel_mm_s2[1:])
    apply = (L < SMALL_SEGMENT_MM) & (c > SMALL_SEGMENT_COS)
    return np.sqrt(np.where(apply, L * a / theta, np.inf))


def junction_limits(turn_cos: np.ndarray, accel_mm_s2: np.ndarray, deviation_mm: np.ndarray,
                    centripetal_len_mm: np.ndarray | None, jerk_v_mm_s: np.ndarray | None,
                    vcap_mm_s: np.ndarray, stop_after: np.ndarray,
                    small_segment_len_mm: np.ndarray | None = None) -> np.ndarray:
    """(N-1,) inner junction speeds with a junction deviation per junction, Klipper's
    centripetal rule (when lengths are given), Marlin's small-segment rule (when
    ``small_segment_len_mm`` is given), classic jerk where ``jerk_v_mm_s`` is finite, the
    neighbours' caps and exact stops. Shared by the planners and the firmware models."""
    n = vcap_mm_s.size
    free = np.full(n, np.inf)
    never = np.zeros(n, bool)
    inner = junction_speeds(turn_cos, accel_mm_s2, 1.0, free, never)[1:n] * np.sqrt(deviation_mm)
    if centripetal_len_mm is not None:
        cen = junction_speeds(turn_cos, accel_mm_s2, np.inf, free, never, centripetal_len_mm)[1:n]
        inner = np.minimum(inner, cen)
    if small_segment_len_mm is not None and n > 1:
        inner = np.minimum(inner, small_segment_limits(turn_cos, accel_mm_s2,
                                                       small_segment_len_mm))
    if jerk_v_mm_s is not None:
        inner = np.where(np.isfinite(jerk_v_mm_s), jerk_v_mm_s, inner)
    inner = np.minimum(inner, np.minimum(vcap_mm_s[:-1], vcap_mm_s[1:]))
    return np.where(stop_after[:-1], 0.0, inner)


def forward_backward(vj_mm_s: np.ndarray, length_mm: np.ndarray,
                     accel_mm_s2: np.ndarray) -> np.ndarray:
    """Lower the junction limits so each segment can go from its entry to its exit speed.

    Args:
        vj_mm_s: (N+1,) junction speed limits (ends 0).
        length_mm, accel_mm_s2: (N,) per segment.

    Returns:
        (N+1,) feasible junction speeds, mm/s.
    """
    v2 = np.square(vj_mm_s).tolist()
    two_al = (2.0 * accel_mm_s2 * length_mm).tolist()
    n = len(two_al)
    # backward: entry of i limited by exit of i
    for i in range(n - 1, -1, -1):
        lim = v2[i + 1] + two_al[i]
        if v2[i] > lim:
            v2[i] = lim
    # forward: exit of i limited by entry of i
    for i in range(n):
        lim = v2[i] + two_al[i]
        if v2[i + 1] > lim:
            v2[i + 1] = lim
    return np.sqrt(np.asarray(v2))


@dataclass(frozen=True)
class Trapezoids:
    """Per-segment speed profiles (N segments).

    Attributes:
        v0_mm_s, v1_mm_s, vc_mm_s: (N,) entry, exit and peak (cruise) speed.
        accel_mm_s2: (N,) acceleration used.
        t_acc_s, t_cru_s, t_dec_s: (N,) phase durations.
        d_acc_mm, d_cru_mm: (N,) distance covered in the first two phases.
        dwell_s: (N,) standstill after the segment.
        t0_s: (N+1,) start time of each segment's block (block = phases + dwell); t0[N] is
            the total duration.
        lead_s: standstill before the first segment.
    """

    v0_mm_s: np.ndarray
    v1_mm_s: np.ndarray
    vc_mm_s: np.ndarray
    accel_mm_s2: np.ndarray
    t_acc_s: np.ndarray
    t_cru_s: np.ndarray
    t_dec_s: np.ndarray
    d_acc_mm: np.ndarray
    d_cru_mm: np.ndarray
    dwell_s: np.ndarray
    t0_s: np.ndarray
    lead_s: float

    @property
    def duration_s(self) -> float:
        return float(self.t0_s[-1])

    @property
    def motion_s(self) -> np.ndarray:
        return self.t_acc_s + self.t_cru_s + self.t_dec_s


def peak_speed(v0, v1, accel, length, vcap):
    """Top speed of a trapezoid from entry v0 to exit v1 over ``length`` at ``accel``, capped
    at ``vcap`` (never below the faster end), mm/s."""
    peak = np.sqrt(np.maximum((2.0 * accel * length + v0 * v0 + v1 * v1) / 2.0, 0.0))
    return np.maximum(np.minimum(vcap, peak), np.maximum(v0, v1))


def trapezoids(vj_mm_s: np.ndarray, length_mm: np.ndarray, accel_mm_s2: np.ndarray,
               vcap_mm_s: np.ndarray, dwell_s: np.ndarray, lead_s: float = 0.0) -> Trapezoids:
    """Phases of every segment given feasible junction speeds (from :func:`forward_backward`)."""
    v0 = vj_mm_s[:-1]
    v1 = vj_mm_s[1:]
    a = accel_mm_s2
    L = length_mm
    vc = peak_speed(v0, v1, a, L, vcap_mm_s)
    t_acc = (vc - v0) / a
    t_dec = (vc - v1) / a
    d_acc = (vc * vc - v0 * v0) / (2.0 * a)
    d_dec = (vc * vc - v1 * v1) / (2.0 * a)
    d_cru = np.maximum(L - d_acc - d_dec, 0.0)
    t_cru = np.where(vc > 0, d_cru / np.where(vc > 0, vc, 1.0), 0.0)
    block = t_acc + t_cru + t_dec + dwell_s
    t0 = np.concatenate([[lead_s], lead_s + np.cumsum(block)])
    return Trapezoids(v0, v1, vc, a, t_acc, t_cru, t_dec, d_acc, d_cru, dwell_s, t0, lead_s)


def trapezoids_from_speeds(v0_mm_s, vc_mm_s, v1_mm_s, length_mm, accel_mm_s2, dwell_s,
                           lead_s: float = 0.0) -> Trapezoids:
    """Phases of every segment given its entry, cruise and exit speeds (vc ≥ v0, v1), each
    phase's time its distance over its mean speed (as Klipper times them)."""
    v0, vc, v1, a, L = v0_mm_s, vc_mm_s, v1_mm_s, accel_mm_s2, length_mm
    t_acc = (vc - v0) / a
    t_dec = (vc - v1) / a
    d_acc = (vc * vc - v0 * v0) / (2.0 * a)
    d_dec = (vc * vc - v1 * v1) / (2.0 * a)
    d_cru = np.maximum(L - d_acc - d_dec, 0.0)
    t_cru = np.where(vc > 0, d_cru / np.where(vc > 0, vc, 1.0), 0.0)
    block = t_acc + t_cru + t_dec + dwell_s
    t0 = np.concatenate([[lead_s], lead_s + np.cumsum(block)])
    return Trapezoids(v0, v1, vc, a, t_acc, t_cru, t_dec, d_acc, d_cru, dwell_s, t0, lead_s)


def sample(tr: Trapezoids, s0_mm: np.ndarray, ts_s: float) -> np.ndarray:
    """Path coordinate at t_k = k·ts_s for k = 0..K-1, with K = ceil(duration/ts) + 1, so the
    last sample is at or after the end (s = total length there).

    Returns:
        (K,) s_mm, non-decreasing.
    """
    total_t = tr.duration_s
    k = int(np.ceil(total_t / ts_s - 1e-9)) + 1
    t = np.arange(k) * ts_s
    n = s0_mm.size - 1
    if n == 0:
        return np.zeros(k)
    i = np.clip(np.searchsorted(tr.t0_s, t, side="right") - 1, 0, n - 1)
    tau = t - tr.t0_s[i]
    v0 = tr.v0_mm_s[i]
    a = tr.accel_mm_s2[i]
    ta = tr.t_acc_s[i]
    tc = tr.t_cru_s[i]
    td = tr.t_dec_s[i]
    vc = tr.vc_mm_s[i]
    L = s0_mm[i + 1] - s0_mm[i]
    s_acc = v0 * tau + 0.5 * a * tau * tau
    s_cru = tr.d_acc_mm[i] + vc * (tau - ta)
    t3 = tau - ta - tc
    s_dec = tr.d_acc_mm[i] + tr.d_cru_mm[i] + vc * t3 - 0.5 * a * t3 * t3
    s = np.where(tau < ta, s_acc, np.where(tau < ta + tc, s_cru, np.where(tau < ta + tc + td,
                                                                        s_dec, L)))
    s = np.where(tau < 0, 0.0, s)  # lead-in standstill
    s = s0_mm[i] + np.clip(s, 0.0, L)
    s = np.maximum.accumulate(s)
    s[-1] = s0_mm[-1]
    return s


def times_at_boundaries(tr: Trapezoids) -> tuple[np.ndarray, np.ndarray]:
    """(N,) time each segment's motion starts and (N,) time it ends, s."""
    start = tr.t0_s[:-1]
    return start, start + tr.motion_s
