"""Speed policy: what caps each move's feed before any planner sees it (issue 20 point 1).

The slicer's speeds are the user's decisions — first layer for adhesion, outer walls for the
surface, bridges and overhangs for the plastic, cooling slow-downs for small layers — so by
default (``slicer``) every move's sliced F is its ceiling: the time comes from acceleration and
cornering, never from running a move faster than it was sliced. ``machine`` lets the planners
run moves up to the machine's limits (the profile's V_max and axis feeds), except that the
first layer keeps its sliced speeds and, where the profile states the hotend's volumetric
limit, no extruding move asks for more plastic per second than it melts.

Pure functions of a Path; the planners apply the ceiling as ``Path.feed_mm_s`` with
``use_slicer_feed`` (plan.kinematic.planner_limits).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..gcode.path import Path

#: the policies, default first
SPEEDS = ("slicer", "machine")
#: filament diameter when the profile states none, mm (the common size; 2.85 mm printers
#: state theirs in the profile)
FILAMENT_DIAMETER_MM = 1.75


def feed_ceiling(path: Path, speed: str, *, machine_vmax_mm_s: float = math.inf,
                 max_volumetric_mm3_s: float | None = None,
                 filament_diameter_mm: float = FILAMENT_DIAMETER_MM) -> np.ndarray:
    """(N,) the highest feed each segment may be planned at under ``speed``, mm/s
    (the machine's axis limits apply on top).

    - ``slicer``: the sliced F of every move;
    - ``machine``: ``machine_vmax_mm_s`` (the profile's V_max or ``--vmax``), or the sliced F
      where that is higher (a travel sliced faster than V_max is not slowed: ``machine`` is
      never slower than ``slicer``); the first layer (``layer == 0``: every move up to the
      first extrusion above the first layer's height) and numbered lines at their sliced F;
      an extruding move at most ``max_volumetric_mm3_s`` / (filament area × dE/L) when given.
    """
    if speed not in SPEEDS:
        raise ValueError(f"unknown speed policy {speed!r}; use one of {', '.join(SPEEDS)}")
    feed = np.asarray(path.feed_mm_s, float)
    if speed == "slicer":
        return feed.copy()
    cap = np.maximum(feed, machine_vmax_mm_s)
    keep = (path.layer == 0) | path.fixed
    cap[keep] = feed[keep]
    if max_volumetric_mm3_s is not None:
        area = math.pi * (0.5 * filament_diameter_mm) ** 2
        L = path.length_mm
        with np.errstate(divide="ignore", invalid="ignore"):
            per_mm = np.where((L > 0) & (path.de_mm > 0), path.de_mm / np.where(L > 0, L, 1.0), 0.0)
            flow_cap = np.where(per_mm > 0, max_volumetric_mm3_s / (per_mm * area), math.inf)
        cap = np.minimum(cap, flow_cap)
    return cap


def planning_path(path: Path, speed: str, profile, vmax_mm_s: float | None = None) -> Path:
    """The path with ``feed_mm_s`` replaced by :func:`feed_ceiling` under ``speed`` (what the
    planners cap each move at; the writer and the timings keep the original path).
    ``vmax_mm_s``: ``--vmax`` (default: the profile's V_max, under ``machine``)."""
    lim = profile.limits
    ceiling = feed_ceiling(path, speed,
                           machine_vmax_mm_s=lim.vmax_mm_s if vmax_mm_s is None else vmax_mm_s,
                           max_volumetric_mm3_s=lim.max_volumetric_mm3_s,
                           filament_diameter_mm=lim.filament_diameter_mm)
    return dataclasses.replace(path, feed_mm_s=ceiling)


def plan_vmax(profile, speed: str, vmax_mm_s: float | None) -> float:
    """The path feed cap the planners run under: ``--vmax`` when given, else the machine's
    own X/Y feed limits — the policy's ceiling (:func:`planning_path`) caps each move, not the
    profile's V_max: a V_max below the slicer's travel speed made the output slower than the
    input."""
    if vmax_mm_s is not None:
        return vmax_mm_s
    return max(profile.limits.axis_vmax_mm_s["x"], profile.limits.axis_vmax_mm_s["y"])
