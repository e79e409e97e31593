"""The settings a file sets, replayed once per file, and what the stages read from them.

:class:`Replay` applies the file's lines (M204, M201, SET_VELOCITY_LIMIT, ...) to the
profile's starting limits once, keeping the limits in force after each line; a move looks its
limits up. The planner (:meth:`Replay.move_limits`), the writer
(:meth:`Replay.accel_settings`, :meth:`Replay.accel_clamp`), the ``--accel plan`` override
(override.py) and the firmware model (blocks.py) all read the same replay.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import initial_limits
from .blocks import build_blocks
from .variants import firmware_for


@dataclass(frozen=True)
class MoveLimits:
    """The firmware's limits in force at every move of a program (M moves).

    accel_mm_s2: (M,) M204 P (extruding) or T (travel) — Klipper: its one accel;
    max_accel_mm_s2, max_feed_mm_s: (M, 3) M201 / M203 for X, Y, Z (Klipper: the profile's,
    which the file cannot change; Z: max_z_accel / max_z_velocity);
    jd_mm: (M,) junction deviation (Klipper: from square_corner_velocity and its one accel);
    jerk_mm_s: (M, 3) classic jerk, NaN where junction deviation applies;
    velocity_mm_s: (M,) Klipper's max velocity (inf for Marlin);
    e_accel_mm_s2, e_feed_mm_s: (M,) what an E-only move (retraction, prime) runs at: M204 R
    within M201 E, and M203 E (its own F capped there); Klipper: the extrude-only limits."""

    accel_mm_s2: np.ndarray
    max_accel_mm_s2: np.ndarray
    max_feed_mm_s: np.ndarray
    jd_mm: np.ndarray
    jerk_mm_s: np.ndarray
    velocity_mm_s: np.ndarray
    e_accel_mm_s2: np.ndarray
    e_feed_mm_s: np.ndarray
    #: Klipper: (M,) minimum_cruise_ratio and the M221 extrusion factor (Marlin: 0 and 1)
    min_cruise_ratio: np.ndarray | None = None
    extrude_factor: np.ndarray | None = None


@dataclass(frozen=True)
class AccelSettings:
    """The settings a writer changes to slow a stretch down and restores after it, in force
    at every move (M moves): M204 P and T (Klipper: its one accel, both), classic jerk X/Y
    (NaN where junction deviation applies; Marlin) and square_corner_velocity (Klipper)."""

    flavour: str
    accel_print_mm_s2: np.ndarray
    accel_travel_mm_s2: np.ndarray
    jerk_xy_mm_s: np.ndarray
    scv_mm_s: np.ndarray
    #: (M, 2) M201 X, Y in force (Klipper: the profile's, which the file cannot change)
    max_accel_xy_mm_s2: np.ndarray | None = None
    #: (M,) M204 R in force (Marlin's E-only moves; Klipper ignores M204 R)
    accel_retract_mm_s2: np.ndarray | None = None
    #: (M,) Marlin's junction deviation M205 J in force
    jd_mm: np.ndarray | None = None


@dataclass(frozen=True)
class AccelClamp:
    """The acceleration limits a writer must set so the firmware accelerates no harder than
    the plan, at every move (M moves), where the plan's limits (the profile's, ``--amax``) are
    below the file's: Marlin's per-axis maxima ``M201 X Y Z`` (k = 3; the firmware's move
    acceleration is min(M204, M201 scaled to the direction), the plan's the same with the
    profile's axis limits, so clamping M201 makes them equal), Klipper's one ``ACCEL`` (k = 1,
    the vector's norm; the plan caps XY moves at the smaller X/Y limit there too).

    file_mm_s2, want_mm_s2: (M, k) the file's values in force and the clamped ones;
    epoch: (M,) number of the file's lines setting them before each move (a writer's own
    line holds until the file sets them again)."""

    flavour: str
    file_mm_s2: np.ndarray
    want_mm_s2: np.ndarray
    epoch: np.ndarray


class Replay:
    """The limits in force through one program: ``snaps`` (E+1) after each event (the first
    before any), and ``si`` (M,) per move, the index of the snapshot in force at it (after
    every event read before it). The file sets limits a few thousand times at most; a move
    looks its limits up. ``override`` (firmware.AccelOverride): the plan's accelerations over
    the file's lines that lower them."""

    def __init__(self, program, profile, override=None, firmware=None):
        self.program, self.profile, self.override = program, profile, override
        self.firmware = firmware or firmware_for(profile)
        lim = initial_limits(profile)
        snaps = [lim.copy()]
        over = override.events if override is not None else {}
        apply = self.firmware.apply_event
        for k, ev in enumerate(program.events):
            apply(lim, ev)
            if k in over:
                lim.set_fields(over[k])
            snaps.append(lim.copy())
        ev_mi = np.array([ev.move_index for ev in program.events], dtype=np.int64)
        self.snaps = snaps
        self.si = np.searchsorted(ev_mi, np.arange(len(program.moves)), side="right")
        self._move_limits = None
        self._blocks = None
        self._overridden = None

    def overridden(self, override) -> "Replay":
        """The replay of the same program with ``override`` (itself when None); the one
        :func:`firmware.accel_override` made is kept, not replayed again."""
        if override is None:
            return self
        done = self._overridden
        if done is not None and done.override.events is override.events:
            done.override = override
            return done
        self._overridden = Replay(self.program, self.profile, override, self.firmware)
        return self._overridden

    def move_limits(self) -> MoveLimits:
        """What the firmware will allow for each move, honouring the settings found in the
        file, so a planner can stay within them (the firmware would otherwise run our plan
        slower)."""
        if self._move_limits is None:
            self._move_limits = self._make_move_limits()
        return self._move_limits

    def _make_move_limits(self) -> MoveLimits:
        snaps, si, fwv = self.snaps, self.si, self.firmware
        moves = self.program.moves
        de = (np.array([mv.e_end_mm for mv in moves], dtype=float)
              - np.array([mv.e_start_mm for mv in moves], dtype=float))
        acc = np.where(de > 0, np.array([q.accel_print for q in snaps])[si],
                       np.array([q.accel_travel for q in snaps])[si])
        macc = np.array([[q.max_accel[k] for k in "xyz"] for q in snaps]).reshape(-1, 3)[si]
        mfeed = np.array([[q.max_feed[k] for k in "xyz"] for q in snaps]).reshape(-1, 3)[si]
        per = fwv.move_arrays(snaps, si, acc, len(moves))
        jerk = np.array([[np.nan] * 3 if q.jerk is None else [q.jerk[k] for k in "xyz"]
                         for q in snaps]).reshape(-1, 3)[si]
        e_acc = np.array([fwv.e_only_accel(q) for q in snaps])[si]
        e_feed = np.array([q.max_feed["e"] for q in snaps], dtype=float)[si]
        ef = np.array([q.extrude_factor for q in snaps])[si]
        return MoveLimits(acc, macc, mfeed, per["jd"], jerk, per["velocity"], e_acc, e_feed,
                          per["min_cruise_ratio"], ef)

    def accel_settings(self, clamp=None) -> AccelSettings:
        """:class:`AccelSettings` of the program (the profile's, then the file's own
        settings); with a Klipper :class:`AccelClamp`, its one accel as clamped to the plan's
        limits; with the replay's ``override``, the plan's accelerations where the file's
        lines lower them (what the writer's lines leave in force)."""
        snaps, si, fwv = self.snaps, self.si, self.firmware
        jerk = np.array([fwv.settings_jerk(q) for q in snaps]).reshape(-1, 2)
        acc_p = np.array([q.accel_print for q in snaps])[si]
        acc_t = np.array([q.accel_travel for q in snaps])[si]
        acc_p, acc_t = fwv.settings_accel(acc_p, acc_t, clamp)
        macc = np.array([[q.max_accel["x"], q.max_accel["y"]] for q in snaps]).reshape(-1, 2)[si]
        return AccelSettings(fwv.flavour, acc_p, acc_t, jerk[si],
                             np.array([q.scv for q in snaps])[si], macc,
                             np.array([q.accel_retract for q in snaps])[si],
                             np.array([q.jd for q in snaps])[si])

    def accel_clamp(self, axis_amax_mm_s2: dict) -> AccelClamp | None:
        """:class:`AccelClamp` of the program under the plan's axis limits (plan.kinematic
        .effective_limits), or None when the file's settings are never above them. The
        file's values are those in force with the replay's ``override``."""
        program, si = self.program, self.si
        file, cap, sets = self.firmware.clamp_values(self.snaps, axis_amax_mm_s2,
                                                     program.events)
        if not len(program.moves) or not np.any(file[np.unique(si)] > cap):
            return None
        ev_mi = np.array([ev.move_index for ev, hit in zip(program.events, sets) if hit],
                         dtype=np.int64)
        epoch = np.searchsorted(ev_mi, np.arange(len(program.moves)), side="right")
        return AccelClamp(self.firmware.flavour, file[si], np.minimum(file[si], cap), epoch)

    def blocks(self):
        """The firmware's planner blocks (blocks.build_blocks), built once."""
        if self._blocks is None:
            self._blocks = build_blocks(self)
        return self._blocks


def move_limits(program, profile, override=None) -> MoveLimits:
    """:meth:`Replay.move_limits` of ``program`` (``override``: firmware.accel_override)."""
    return Replay(program, profile, override).move_limits()


def accel_settings(program, profile, clamp=None, override=None) -> AccelSettings:
    """:meth:`Replay.accel_settings` of ``program``."""
    return Replay(program, profile, override).accel_settings(clamp)


def accel_clamp(program, profile, axis_amax_mm_s2: dict, override=None) -> AccelClamp | None:
    """:meth:`Replay.accel_clamp` of ``program``."""
    return Replay(program, profile, override).accel_clamp(axis_amax_mm_s2)
