"""Commanded trajectories sampled at a fixed period."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Trajectory:
    """A commanded (or executed) trajectory sampled every ``ts_s`` seconds.

    Attributes:
        ts_s: sample period, s.
        pos_mm: np.ndarray, shape (K, 3). X, Y, Z position at ``t_k = k * ts_s``, mm.
        e_mm: np.ndarray, shape (K,). Absolute filament position, mm.
        in_extrusion: np.ndarray, shape (K,) bool, or None. Where the source knows its moves
            (the firmware model's blocks): the sample lies in an XY move that extrudes. It
            tells an interval in which a travel stops and an E-only prime starts (both
            advance within one Ts) from one that extrudes along the path.
    """

    ts_s: float
    pos_mm: np.ndarray
    e_mm: np.ndarray
    in_extrusion: np.ndarray | None = None

    def __post_init__(self):
        if self.pos_mm.ndim != 2 or self.pos_mm.shape[1] != 3:
            raise ValueError(f"pos_mm must have shape (K, 3), got {self.pos_mm.shape}")
        if self.e_mm.shape != (self.pos_mm.shape[0],):
            raise ValueError(f"e_mm must have shape ({self.pos_mm.shape[0]},), got {self.e_mm.shape}")

    @property
    def n_samples(self) -> int:
        return int(self.pos_mm.shape[0])

    @property
    def t_s(self) -> np.ndarray:
        """Shape (K,). Sample times, s."""
        return np.arange(self.n_samples) * self.ts_s

    @property
    def duration_s(self) -> float:
        return max(self.n_samples - 1, 0) * self.ts_s
