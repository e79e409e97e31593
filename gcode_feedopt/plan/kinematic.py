"""The kinematic planner: time-optimal path speed under feed, per-axis acceleration and the
firmware's junction rule, sampled at Ts. The first optimizer, and later the baseline.

Limits, per segment:
- speed: the profile's V_max (or the override), each axis's maximum feed projected on the
  direction, optionally the slicer's F; on arcs also the centripetal limit v²/R ≤ A (what
  Marlin's small-segment junction rule gives the chords it cuts an arc into);
- acceleration along the path: min over axes of A_axis/|u_axis| on lines (so no axis ever
  exceeds its limit in the tangential phases); on arcs min(A_x, A_y), as the firmware
  accelerates the chords. An A/2 tangential + A/2 centripetal split would keep every axis
  within A on the arc, but the firmware does not apply it: the file ran arcs 1.2 % faster than
  such a plan (ArcWelder Benchy), so the twin would have judged a slower motion than the one
  executed. Tangential and centripetal parts then add up to at most √2·A on an axis, as on the
  chords of any polyline curve; the twin judges the resulting contour error.
- junctions: the firmware's own junction rule (Marlin's junction deviation, or Klipper's
  rules: square-corner velocity per neighbour, its centripetal limit and the extruder's corner
  velocity), so a plan never asks for a corner speed the firmware would refuse — the written
  G-code then runs as planned. Full reversals, E-only moves, dwells, waits and tool changes are
  exact stops.
- Klipper: also its look-ahead with minimum_cruise_ratio (plan.trapezoid.klipper_lookahead)
  and its extrude-only limits on retracting moves: the plan is Klipper's own plan
  (docs/firmware.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..gcode.path import SEG_LINE, Path
from ..gcode.schedule import Schedule, SegmentPlan
from .trapezoid import (Trapezoids, forward_backward, junction_limits, klipper_junction_v2,
                        klipper_lookahead, sample, trapezoids)


def _axis_caps(path: Path, axis_limit: dict, scalar_cap: float | None) -> np.ndarray:
    """(N,) highest path-direction value such that no axis exceeds its own limit."""
    t_beg, t_end = path.end_tangents()
    # the worse of the two ends (arcs turn); for lines both are equal
    u = np.maximum(np.abs(t_beg), np.abs(t_end))
    lim = np.array([axis_limit["x"], axis_limit["y"], axis_limit["z"]], dtype=float)
    with np.errstate(divide="ignore"):
        caps = np.where(u > 1e-12, lim[None, :] / u, np.inf).min(axis=1)
    arc = path.kind != SEG_LINE
    if np.any(arc):
        # along an arc the direction sweeps: both X and Y see the full value at some point
        caps[arc] = np.minimum(caps[arc], min(lim[0], lim[1]))
    if scalar_cap is not None:
        caps = np.minimum(caps, scalar_cap)
    return caps


def _klipper_norm_cap(path: Path, acc: np.ndarray, axis_limit: dict, firmware) -> np.ndarray:
    """Klipper has one acceleration, the vector's norm: where the writer clamps it to the
    plan's limits (vm.firmware.accel_clamp) a diagonal XY move gets no more than an axis."""
    if firmware.flavour != "klipper":
        return acc
    t_beg, _ = path.end_tangents()
    xy = np.hypot(t_beg[:, 0], t_beg[:, 1]) > 1e-12
    acc = acc.copy()
    acc[xy] = np.minimum(acc[xy], min(axis_limit["x"], axis_limit["y"]))
    return acc


def deviation_for(firmware, accel_mm_s2: float) -> tuple[float, bool]:
    """Junction deviation (mm) of the firmware and whether Klipper's centripetal rule applies."""
    if firmware.flavour == "klipper":
        scv = firmware.square_corner_velocity_mm_s
        return scv * scv * (math.sqrt(2.0) - 1.0) / accel_mm_s2, True
    return firmware.junction_deviation_mm, False


def _firmware_caps(path: Path, fw_limits):
    """Per-segment accel cap, feed cap, junction deviation and jerk-rule junction speeds from
    the firmware's limits in force at each move (vm.firmware.move_limits)."""
    mi = path.move_index
    t_beg, t_end = path.end_tangents()
    u = np.maximum(np.abs(t_beg), np.abs(t_end))
    with np.errstate(divide="ignore", invalid="ignore"):
        a_axis = np.where(u > 1e-12, fw_limits.max_accel_mm_s2[mi] / u, np.inf).min(axis=1)
        v_axis = np.where(u > 1e-12, fw_limits.max_feed_mm_s[mi] / u, np.inf).min(axis=1)
    acc = np.minimum(fw_limits.accel_mm_s2[mi], a_axis)
    vcap = np.minimum(v_axis, fw_limits.velocity_mm_s[mi])
    jd = fw_limits.jd_mm[mi]
    jerk = fw_limits.jerk_mm_s[mi]
    jerk_v = None
    if np.any(np.isfinite(jerk[:, 0])) and path.n_segments > 1:
        dv = np.abs(t_beg[1:] - t_end[:-1])
        with np.errstate(divide="ignore", invalid="ignore"):
            jerk_v = np.where(dv > 1e-12, jerk[1:] / dv, np.inf).min(axis=1)
        # finite only where classic jerk is on; junction_limits uses the deviation elsewhere
        jerk_v = np.where(np.isfinite(jerk[1:, 0]), jerk_v, np.inf)
    return acc, vcap, jd, jerk_v


def writer_accel(path: Path, profile, fw_limits=None, amax_mm_s2: float | None = None):
    """(N,) the acceleration the firmware will use on each segment (for the writer's check
    that one line per move reproduces the plan)."""
    acc = segment_accel(path, profile, amax_mm_s2)
    if fw_limits is not None:
        acc = np.minimum(acc, _firmware_caps(path, fw_limits)[0])
    return acc


@dataclass(frozen=True)
class PlannerLimits:
    """What the look-ahead planner must respect on a path of N segments.

    Attributes:
        vcap_mm_s: (N,) speed cap of each segment, mm/s.
        accel_mm_s2: (N,) acceleration along each segment, mm/s².
        junction_mm_s: (N+1,) highest speed at each junction (0 at both ends and at exact
            stops), before the look-ahead lowers them to what the accelerations allow, mm/s.
        jerk_junction: (N+1,) bool, junctions set by classic jerk (the settings of the move
            after the junction alone), or None: none is.
    """

    vcap_mm_s: np.ndarray
    accel_mm_s2: np.ndarray
    junction_mm_s: np.ndarray
    jerk_junction: np.ndarray | None = None
    #: Klipper: (N,) minimum_cruise_ratio's pseudo-accel of each segment (its look-ahead gives
    #: a run of short moves one reduced peak, plan.trapezoid.klipper_lookahead); None: Marlin
    pseudo_accel_mm_s2: np.ndarray | None = None


def planner_limits(path: Path, *, vmax_mm_s: float, axis_vmax_mm_s: dict,
                   axis_amax_mm_s2: dict, firmware, use_slicer_feed: bool = False,
                   feed_scale: float = 1.0, fw_limits=None) -> PlannerLimits:
    """Feed caps, per-move accelerations and junction speeds of the path (module docstring).

    ``fw_limits`` (vm.firmware.move_limits): the firmware's settings in force at each move
    (M201/M203/M204/M205, SET_VELOCITY_LIMIT found in the file); the plan stays within them
    so the firmware runs it as planned."""
    n = path.n_segments
    vcap = _axis_caps(path, axis_vmax_mm_s, vmax_mm_s)
    if use_slicer_feed:
        vcap = np.minimum(vcap, path.feed_mm_s * feed_scale)
    acc = _klipper_norm_cap(path, _axis_caps(path, axis_amax_mm_s2, None), axis_amax_mm_s2,
                            firmware)
    arc = path.kind != SEG_LINE
    if np.any(arc):
        a_xy = min(axis_amax_mm_s2["x"], axis_amax_mm_s2["y"])
        vcap[arc] = np.minimum(vcap[arc], np.sqrt(a_xy * path.radius_mm[arc]))
    # numbered (fixed) lines keep the slicer's speed: they are written back unchanged
    vcap = np.where(path.fixed, np.minimum(vcap, path.feed_mm_s), vcap)
    if firmware.flavour == "klipper":
        return _klipper_limits(path, vcap, acc, axis_amax_mm_s2, firmware, fw_limits)
    jerk_v = None
    if fw_limits is not None:
        f_acc, f_vcap, jd, jerk_v = _firmware_caps(path, fw_limits)
        acc = np.minimum(acc, f_acc)
        vcap = np.minimum(vcap, f_vcap)
    else:
        a_ref = float(np.median(acc)) if n else 1.0
        jd = np.full(n, deviation_for(firmware, a_ref)[0])
    vj = np.zeros(n + 1)
    if n:
        vj[1:n] = junction_limits(path.junction_cos(), acc, jd[1:], None, jerk_v, vcap,
                                  path.stop_after, path.length_mm)
    jerk_j = None
    if jerk_v is not None and n:
        jerk_j = np.zeros(n + 1, bool)
        jerk_j[1:n] = np.isfinite(jerk_v)
    return PlannerLimits(vcap_mm_s=vcap, accel_mm_s2=acc, junction_mm_s=vj, jerk_junction=jerk_j)


def _klipper_limits(path: Path, vcap: np.ndarray, acc: np.ndarray, axis_amax_mm_s2: dict,
                    firmware, fw_limits) -> PlannerLimits:
    """:class:`PlannerLimits` under Klipper's rules (vm.firmware's Klipper model), given the
    plan's own caps ``vcap`` and ``acc``.

    Klipper's one accel is what the writer leaves in force: the file's (M204 S, M204 P T,
    SET_VELOCITY_LIMIT ACCEL), clamped to the plan's X/Y limit (vm.firmware.accel_clamp);
    its junction deviation comes from that accel and square_corner_velocity, and each side of
    a junction gets δ·a with its own segment's accel (so moves slowed by Z get slower
    corners). A segment that retracts, or extrudes without moving X/Y, stays within the
    extrude-only limits scaled by L/|dE|; where the extruder's share dE/L changes, the
    junction stays within instantaneous_corner_velocity / |Δ(dE/L)|; minimum_cruise_ratio
    gives the plan its pseudo-accel (plan.trapezoid.klipper_lookahead)."""
    n = path.n_segments
    L = path.length_mm
    a_xy = min(axis_amax_mm_s2["x"], axis_amax_mm_s2["y"])
    if fw_limits is not None:
        mi = path.move_index
        f_acc, f_vcap, jd_file, _ = _firmware_caps(path, fw_limits)
        acc = np.minimum(acc, f_acc)
        vcap = np.minimum(vcap, f_vcap)
        file_a = fw_limits.accel_mm_s2[mi]
        toolhead = np.minimum(file_a, a_xy)
        jd = jd_file * file_a / toolhead
        mcr = fw_limits.min_cruise_ratio[mi]
        ef = fw_limits.extrude_factor[mi]
        e_feed, e_acc = fw_limits.e_feed_mm_s[mi], fw_limits.e_accel_mm_s2[mi]
    else:
        toolhead = np.full(n, min(firmware.accel_mm_s2, a_xy))
        scv = firmware.square_corner_velocity_mm_s
        jd = scv * scv * (math.sqrt(2.0) - 1.0) / toolhead
        mcr = np.full(n, firmware.minimum_cruise_ratio)
        ef = np.ones(n)
        e_feed = np.full(n, firmware.max_feed_mm_s["e"])
        e_acc = np.full(n, firmware.max_accel_mm_s2["e"])
    with np.errstate(divide="ignore", invalid="ignore"):
        e_ratio = np.where(L > 0, path.de_mm * ef / np.where(L > 0, L, 1.0), 0.0)
        no_xy = ((path.end_mm[:, 0] == path.start_mm[:, 0])
                 & (path.end_mm[:, 1] == path.start_mm[:, 1]) & (path.kind == SEG_LINE))
        e_lim = (e_ratio != 0.0) & (no_xy | (e_ratio < 0.0))
        inv = 1.0 / np.abs(e_ratio)
        vcap = np.where(e_lim, np.minimum(vcap, e_feed * inv), vcap)
        acc = np.where(e_lim, np.minimum(acc, e_acc * inv), acc)
    vj = np.zeros(n + 1)
    if n:
        vj[1:n] = np.sqrt(klipper_junction_v2(path.junction_cos(), acc, jd, L, vcap,
                                              path.stop_after, e_ratio,
                                              firmware.instantaneous_corner_velocity_mm_s))
    pseudo = np.minimum(acc, toolhead * (1.0 - mcr))
    return PlannerLimits(vcap_mm_s=vcap, accel_mm_s2=acc, junction_mm_s=vj,
                         pseudo_accel_mm_s2=pseudo)


def plan_trapezoids(path: Path, *, vmax_mm_s: float, axis_vmax_mm_s: dict,
                    axis_amax_mm_s2: dict, firmware, use_slicer_feed: bool = False,
                    feed_scale: float = 1.0, fw_limits=None, with_limits: bool = False):
    """Look-ahead trapezoid plan of the whole path under :func:`planner_limits` (and those
    limits, ``with_limits``)."""
    lim = planner_limits(path, vmax_mm_s=vmax_mm_s, axis_vmax_mm_s=axis_vmax_mm_s,
                         axis_amax_mm_s2=axis_amax_mm_s2, firmware=firmware,
                         use_slicer_feed=use_slicer_feed, feed_scale=feed_scale,
                         fw_limits=fw_limits)
    if lim.pseudo_accel_mm_s2 is not None:
        tr = klipper_lookahead(np.square(lim.junction_mm_s), path.length_mm, lim.accel_mm_s2,
                               lim.pseudo_accel_mm_s2, lim.vcap_mm_s, path.dwell_after_s,
                               path.dwell_before_s)
    else:
        vj = forward_backward(lim.junction_mm_s, path.length_mm, lim.accel_mm_s2)
        tr = trapezoids(vj, path.length_mm, lim.accel_mm_s2, lim.vcap_mm_s, path.dwell_after_s,
                        path.dwell_before_s)
    return (tr, lim) if with_limits else tr


def segment_plan(peak_mm_s: np.ndarray, accel_mm_s2: np.ndarray,
                 jerk_junction: np.ndarray | None) -> SegmentPlan:
    """What the writer needs to write a planned segment as one line at its peak speed
    (gcode.pieces.plan_peaks): the peak and acceleration of every segment's trapezoid, and
    ``exact`` (N,): the firmware's junction speeds at both ends do not depend on F. Classic
    jerk's do (Marlin limits the junction by the jerk of the two moves at their nominal
    speeds), so a line at the peak instead of the plan's cap may cross such a junction faster
    than planned."""
    n = peak_mm_s.size
    jerk = (np.zeros(n + 1, bool) if jerk_junction is None
            else np.asarray(jerk_junction, bool))
    return SegmentPlan(peak_mm_s=peak_mm_s, accel_mm_s2=accel_mm_s2,
                       exact=~(jerk[:-1] | jerk[1:]))


def effective_limits(profile, vmax_mm_s: float | None = None, amax_mm_s2: float | None = None):
    """(vmax, axis_vmax, axis_amax): the profile's limits, overridden, and never above the
    firmware's own maxima (M203/M201 of the profile)."""
    lim = profile.limits
    fw = profile.firmware
    vmax = lim.vmax_mm_s if vmax_mm_s is None else float(vmax_mm_s)
    amax = lim.amax_mm_s2 if amax_mm_s2 is None else float(amax_mm_s2)
    axis_a = dict(lim.axis_amax_mm_s2)
    axis_a["x"] = min(axis_a["x"], amax)
    axis_a["y"] = min(axis_a["y"], amax)
    for k in ("x", "y", "z"):
        axis_a[k] = min(axis_a[k], fw.max_accel_mm_s2[k])
    axis_v = {k: min(lim.axis_vmax_mm_s[k], fw.max_feed_mm_s[k]) for k in ("x", "y", "z")}
    return vmax, axis_v, axis_a


def segment_accel(path: Path, profile, amax_mm_s2: float | None = None) -> np.ndarray:
    """(N,) acceleration along each segment that keeps every axis within its limit."""
    _, _, axis_a = effective_limits(profile, None, amax_mm_s2)
    acc = _klipper_norm_cap(path, _axis_caps(path, axis_a, None), axis_a, profile.firmware)
    return acc


def plan_kinematic(path: Path, profile, *, use_slicer_feed: bool = False,
                   vmax_mm_s: float | None = None, amax_mm_s2: float | None = None,
                   feed_scale: float = 1.0, fw_limits=None) -> Schedule:
    """Time-optimal kinematic schedule of ``path`` under the profile's limits.

    Args:
        path: the parametric path.
        profile: MachineProfile (limits, firmware, ts_s).
        use_slicer_feed: also cap each move at the slicer's F.
        vmax_mm_s, amax_mm_s2: override the profile's V_max and X/Y A_max.
        feed_scale: multiplies the slicer's F when ``use_slicer_feed``.

    Returns:
        Schedule with ``segment_plan`` (every segment is one trapezoid: its peak speed and
        acceleration, for the writer) and ``info``: ``trapezoids`` (the phase plan),
        ``segment_start_s`` and ``segment_end_s`` (N,) motion start/end times.
    """
    vmax, axis_v, axis_a = effective_limits(profile, vmax_mm_s, amax_mm_s2)
    amax = axis_a["x"]
    tr = plan_trapezoids(path, vmax_mm_s=vmax, axis_vmax_mm_s=axis_v, axis_amax_mm_s2=axis_a,
                         firmware=profile.firmware, use_slicer_feed=use_slicer_feed,
                         feed_scale=feed_scale, fw_limits=fw_limits, with_limits=True)
    tr, lim = tr
    s = sample(tr, path.s0_mm, profile.ts_s)
    start = tr.t0_s[:-1]
    return Schedule(ts_s=profile.ts_s, s_mm=s, method="kinematic",
                    info={"trapezoids": tr, "segment_start_s": start,
                          "segment_end_s": start + tr.motion_s, "plan_time_s": tr.duration_s,
                          "vmax_mm_s": vmax, "amax_mm_s2": amax},
                    segment_plan=segment_plan(tr.vc_mm_s, tr.accel_mm_s2, lim.jerk_junction))
