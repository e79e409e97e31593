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
- Klipper: also its look-ahead with minimum_cruise_ratio (firmware.klipper.klipper_lookahead)
  and its extrude-only limits on retracting moves: the plan is Klipper's own plan
  (docs/firmware.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..firmware import by_flavour, firmware_for
from ..firmware.base import segment_caps
from ..gcode.path import SEG_LINE, Path
from ..gcode.schedule import Schedule, SegmentPlan
from .trapezoid import sample


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


def writer_accel(path: Path, profile, fw_limits=None, amax_mm_s2: float | None = None):
    """(N,) the acceleration the firmware will use on each segment (for the writer's check
    that one line per move reproduces the plan)."""
    acc = segment_accel(path, profile, amax_mm_s2)
    if fw_limits is not None:
        acc = np.minimum(acc, segment_caps(path, fw_limits)[0])
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
    #: a run of short moves one reduced peak, firmware.klipper.klipper_lookahead); None: Marlin
    pseudo_accel_mm_s2: np.ndarray | None = None
    #: the firmware variant whose look-ahead plans within these limits (firmware.by_flavour)
    flavour: str = "marlin"


def planner_limits(path: Path, *, vmax_mm_s: float, axis_vmax_mm_s: dict,
                   axis_amax_mm_s2: dict, firmware, use_slicer_feed: bool = False,
                   feed_scale: float = 1.0, fw_limits=None) -> PlannerLimits:
    """Feed caps, per-move accelerations and junction speeds of the path (module docstring).

    ``fw_limits`` (firmware.MoveLimits): the firmware's settings in force at each move
    (M201/M203/M204/M205, SET_VELOCITY_LIMIT found in the file); the plan stays within them
    so the firmware runs it as planned. ``firmware``: the profile's firmware settings; the
    junction rule and the caps are its variant's (firmware.Firmware.planner_limits)."""
    variant = by_flavour(firmware.flavour)
    vcap = _axis_caps(path, axis_vmax_mm_s, vmax_mm_s)
    if use_slicer_feed:
        vcap = np.minimum(vcap, path.feed_mm_s * feed_scale)
    acc = variant.norm_cap(path, _axis_caps(path, axis_amax_mm_s2, None), axis_amax_mm_s2)
    arc = path.kind != SEG_LINE
    if np.any(arc):
        a_xy = min(axis_amax_mm_s2["x"], axis_amax_mm_s2["y"])
        vcap[arc] = np.minimum(vcap[arc], np.sqrt(a_xy * path.radius_mm[arc]))
    # numbered (fixed) lines keep the slicer's speed: they are written back unchanged
    vcap = np.where(path.fixed, np.minimum(vcap, path.feed_mm_s), vcap)
    return PlannerLimits(**variant.planner_limits(path, vcap, acc, axis_amax_mm_s2, firmware,
                                                  fw_limits), flavour=variant.flavour)


def plan_trapezoids(path: Path, *, vmax_mm_s: float, axis_vmax_mm_s: dict,
                    axis_amax_mm_s2: dict, firmware, use_slicer_feed: bool = False,
                    feed_scale: float = 1.0, fw_limits=None, with_limits: bool = False):
    """Look-ahead trapezoid plan of the whole path under :func:`planner_limits` (and those
    limits, ``with_limits``)."""
    lim = planner_limits(path, vmax_mm_s=vmax_mm_s, axis_vmax_mm_s=axis_vmax_mm_s,
                         axis_amax_mm_s2=axis_amax_mm_s2, firmware=firmware,
                         use_slicer_feed=use_slicer_feed, feed_scale=feed_scale,
                         fw_limits=fw_limits)
    tr = by_flavour(firmware.flavour).lookahead(
        lim.junction_mm_s, path.length_mm, lim.accel_mm_s2, lim.pseudo_accel_mm_s2,
        lim.vcap_mm_s, path.dwell_after_s, path.dwell_before_s)
    return (tr, lim) if with_limits else tr


def segment_plan(peak_mm_s: np.ndarray, accel_mm_s2: np.ndarray,
                 jerk_junction: np.ndarray | None,
                 cap_mm_s: np.ndarray | None = None) -> SegmentPlan:
    """What the writer needs to write a planned segment as one line (gcode.pieces.plan_peaks):
    the peak and acceleration of every segment's trapezoid, ``exact`` (N,): the firmware's
    junction speeds at both ends do not depend on F, and the plan's feed cap of each segment.
    Classic jerk's do depend on F (Marlin limits the junction by the jerk of the two moves at
    their nominal speeds), so such a segment is written at the cap its junctions were planned
    with, not at its peak."""
    n = peak_mm_s.size
    jerk = (np.zeros(n + 1, bool) if jerk_junction is None
            else np.asarray(jerk_junction, bool))
    return SegmentPlan(peak_mm_s=peak_mm_s, accel_mm_s2=accel_mm_s2,
                       exact=~(jerk[:-1] | jerk[1:]),
                       cap_mm_s=None if cap_mm_s is None else np.asarray(cap_mm_s, float))


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
    return firmware_for(profile).norm_cap(path, _axis_caps(path, axis_a, None), axis_a)


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
                    segment_plan=segment_plan(tr.vc_mm_s, tr.accel_mm_s2, lim.jerk_junction,
                                              lim.vcap_mm_s))
