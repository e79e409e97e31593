"""The Schedule: what every planner and optimizer returns."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


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
            error. Never a silent None: planners fill what they know.
    """

    ts_s: float
    s_mm: np.ndarray
    method: str
    info: dict = field(default_factory=dict)

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
