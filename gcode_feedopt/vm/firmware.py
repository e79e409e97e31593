"""The firmware model of the virtual machine: G-code -> the commanded trajectory the firmware
will run, at Ts, and the time it takes.

The printer's firmware re-plans every move with its own limits, so the commanded trajectory is
the firmware's. The rules are the firmware package's (Marlin or Klipper by the profile's
``firmware.flavour``: gcode_feedopt.firmware); here its planner blocks
(firmware.blocks) are planned and sampled.
"""

from __future__ import annotations

import math

import numpy as np

from ..firmware import Replay
from ..plan.trapezoid import sample
from .trajectory import Trajectory


def estimate_time_s(program, profile, override=None, replay: Replay | None = None) -> float:
    """Print time as the firmware model executes the program (no sampling), s. ``override``
    (firmware.accel_override): the program timed at the plan's accelerations where the
    file's lines lower them. ``replay``: the program's settings already replayed
    (firmware.Replay, for this profile and override), not replayed again."""
    if replay is None:
        replay = Replay(program, profile, override)
    blocks = replay.blocks()
    if blocks.length_mm.size == 0:
        return blocks.lead_s
    return blocks.plan().duration_s


def execute(program, profile, replay: Replay | None = None) -> Trajectory:
    """The commanded trajectory (X, Y, Z, E at every Ts) the firmware runs for ``program``."""
    blocks = (replay if replay is not None else Replay(program, profile)).blocks()
    ts = profile.ts_s
    if blocks.length_mm.size == 0:
        k = int(math.ceil(blocks.lead_s / ts)) + 1
        return Trajectory(ts_s=ts, pos_mm=np.zeros((k, 3)), e_mm=np.zeros(k))
    tr = blocks.plan()
    s0 = np.concatenate([[0.0], np.cumsum(blocks.length_mm)])
    s = sample(tr, s0, ts)
    i = np.clip(np.searchsorted(s0, s, side="right") - 1, 0, blocks.length_mm.size - 1)
    L = blocks.length_mm[i]
    u = np.clip(np.where(L > 0, (s - s0[i]) / np.where(L > 0, L, 1), 0.0), 0.0, 1.0)
    pos = blocks.start_mm[i] + (blocks.end_mm[i] - blocks.start_mm[i]) * u[:, None]
    e = blocks.e0_mm[i] + blocks.de_mm[i] * u
    xy = np.any(blocks.end_mm[:, :2] != blocks.start_mm[:, :2], axis=1)
    return Trajectory(ts_s=ts, pos_mm=pos, e_mm=e, in_extrusion=(xy & (blocks.de_mm > 0))[i])
