"""The Schedule: what every planner and optimizer returns, and what the writer reads of it
besides the samples (:class:`SegmentPlan`, :class:`SlowdownCells`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True, eq=False)
class SegmentPlan:
    """Every segment's firmware trapezoid, for writing it as one line at its peak speed
    (gcode.pieces.plan_peaks). Made by plan.kinematic.segment_plan.

    Attributes:
        peak_mm_s: (N,) the peak speed of each segment's trapezoid, mm/s.
        accel_mm_s2: (N,) the acceleration of each segment's trapezoid, mm/s².
        exact: (N,) bool, the firmware's junction speeds at both ends of the segment do not
            depend on F (False where classic jerk sets a junction).
        cap_mm_s: (N,) the plan's feed cap of each segment (the nominal speed its junctions
            were planned with), mm/s; None when not known.
    """

    peak_mm_s: np.ndarray
    accel_mm_s2: np.ndarray
    exact: np.ndarray
    cap_mm_s: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class SlowdownCells:
    """The planning cells of a slow-down plan (optimize.slowdown), M cells over N segments:
    the writer cuts the moves through slowed cells at runs of equal acceleration and tells the
    firmware each run's acceleration (gcode.writer.write ``cells``).

    Attributes:
        s0_mm: (M+1,) cell boundaries along the path, mm.
        parent: (M,) int, the segment of each cell (non-decreasing).
        scale: (M,) the plan's scale r of each cell (1: not slowed).
        accel_mm_s2: (M,) the plan's acceleration in each cell (F's times r²), mm/s².
        vcap_mm_s: (M,) the plan's feed cap in each cell (F's times r), mm/s.
        vpeak_mm_s: (M,) the plan's highest speed in each cell, mm/s; None when not known
            (the writer then takes each run's speeds from the samples).
        jerk_junction: (M+1,) bool, the cell boundaries where F's classic jerk sets the
            junction; None when not known (no run's peak is then ruled out by it).
    """

    s0_mm: np.ndarray
    parent: np.ndarray
    scale: np.ndarray
    accel_mm_s2: np.ndarray
    vcap_mm_s: np.ndarray
    vpeak_mm_s: np.ndarray | None = None
    jerk_junction: np.ndarray | None = None


@dataclass(frozen=True)
class Schedule:
    """Path progression sampled at a fixed period.

    Attributes:
        ts_s: sample period, s.
        s_mm: np.ndarray, shape (K,). Arc length along the path at ``t_k = k * ts_s``, mm;
            non-decreasing, ``s_mm[0] == 0`` and ``s_mm[-1]`` equal to the path's total length.
            Exact stops and dwells appear as repeated values.
        method: name of the planner that made it (``kinematic``, ``pidd``, ...).
        info: per-run facts: window statuses, fallbacks used, solver seconds, worst predicted
            error (the report's), and what a planner's callers use (a kinematic plan's
            ``trapezoids``, the ``accel_chosen_mm_s2`` of a slow-down plan). Never a silent
            None: planners fill what they know. The writer reads none of it: what it needs
            besides the samples is typed (``segment_plan``, ``cells``).
        segment_plan: every segment's trapezoid when the plan makes each unslowed segment one
            firmware trapezoid (kinematic and slow-down plans), else None.
        cells: the planning cells of a slow-down plan, else None.
    """

    ts_s: float
    s_mm: np.ndarray
    method: str
    info: dict = field(default_factory=dict)
    segment_plan: SegmentPlan | None = None
    cells: SlowdownCells | None = None

    def __post_init__(self):
        if self.s_mm.ndim != 1 or self.s_mm.size < 1:
            raise ValueError("s_mm must be a non-empty 1-D array")

    @property
    def n_samples(self) -> int:
        return int(self.s_mm.size)

    @property
    def duration_s(self) -> float:
        """Time from the first to the last sample, s."""
        return (self.n_samples - 1) * self.ts_s

    def speed_mm_s(self) -> np.ndarray:
        """Shape (K,). Path speed by backward difference (first sample 0), mm/s."""
        v = np.zeros_like(self.s_mm)
        v[1:] = np.diff(self.s_mm) / self.ts_s
        return v
