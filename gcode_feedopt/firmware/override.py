"""``--accel plan``: the plan's accelerations and junction settings over lower ones the file
sets, and the printer as its owner configured it (``firmware.configured_*``)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from .base import plan_junction
from .replay import Replay
from .variants import by_flavour, firmware_for

#: ``--accel``: ``plan`` — the plan's accelerations (the profile's, within the machine's hardware
#: limits) and junction settings (firmware.plan_junction, where the profile states the
#: hardware's) override lower ones the file sets; ``file`` — the file's own are kept
ACCELS = ("plan", "file")

#: commands that home or probe: a file lowers the acceleration for them on purpose (PrusaSlicer's
#: MINI start block: ``M204 T1250`` before G28/G29, sensorless homing), so a lowering followed
#: by one of them before the next move is kept
_HOMING = frozenset({"G28", "G29", "G30", "G34", "M48", "BED_MESH_CALIBRATE", "PROBE",
                     "QUAD_GANTRY_LEVEL", "Z_TILT_ADJUST", "SCREWS_TILT_CALCULATE"})


@dataclass(frozen=True)
class AccelOverride:
    """The plan's accelerations and junction settings over the file's (``--accel plan``), for
    one program.

    ``events``: event index -> {field: the plan's value} for every line of the file that sets
    an acceleration or a junction setting below the plan's (fields of ``Limits``:
    ``accel_print`` (M204 P, S), ``accel_travel`` (M204 T, S), ``x``, ``y`` (M201 X Y);
    Klipper's one accel is both accels; ``jerk_x``, ``jerk_y`` (Marlin's classic jerk M205 X
    Y), ``jd`` (M205 J), ``scv`` (Klipper's SQUARE_CORNER_VELOCITY), where the profile states
    the hardware's junction limit: ``junction``, the plan's values of those), keyed by the
    event after which they apply: the file's line itself, or the last
    homing or probing command before the next move (the file lowers accelerations for homing on
    purpose: those run at its values). The settings replay (replay.Replay) applies them
    there, as the writer's lines after that line (``lines``: line number -> the commands it
    adds) make the firmware do. ``restore``: the file's own values in force at the last move
    where the plan's hold there, {field: value} (the writer gives them back after the last
    move). M204 R, M201 Z and E stay the file's."""

    flavour: str
    accel_print_mm_s2: float
    accel_travel_mm_s2: float
    max_accel_xy_mm_s2: tuple
    events: dict
    lines: dict
    restore: dict
    #: (line number, command) of every line of the file whose setting is overridden
    sources: tuple = ()
    #: the plan's junction settings the override sets ({field: value} of
    #: firmware.plan_junction; {}: the file's own hold)
    junction: dict = dataclasses.field(default_factory=dict)

    @property
    def n_lines(self) -> int:
        return sum(len(v) for v in self.lines.values())


def plan_accels(profile) -> tuple[float, float, tuple]:
    """(M204 P, M204 T, (M201 X, Y)) the plan runs at: the profile's firmware values within the
    machine's hardware limits (``limits.amax_mm_s2``, ``limits.axis_amax_mm_s2``); Klipper's
    one accel within both axes' limits."""
    return firmware_for(profile).plan_accels(profile)


def accel_override(program, profile, policy: str = "plan",
                   replay: Replay | None = None) -> AccelOverride | None:
    """:class:`AccelOverride` of ``program`` under ``policy`` (:data:`ACCELS`), or None: the
    file's own accelerations hold (``file``, or no line of the file sets one below the plan's
    before a move). ``replay``: the program's own settings replayed (made when not given);
    the replay with the override is kept there (Replay.overridden)."""
    if policy not in ACCELS:
        raise ValueError(f"unknown acceleration policy {policy!r}; use one of {', '.join(ACCELS)}")
    if policy == "file" or not program.moves:
        return None
    raw = replay if replay is not None else Replay(program, profile)
    fwv = raw.firmware
    ap, at, (ax, ay) = fwv.plan_accels(profile)
    plan = {"accel_print": ap, "accel_travel": at, "x": ax, "y": ay}
    pj = plan_junction(profile)
    junction = {f: pj[f] for f in fwv.junction_fields if f in pj}
    plan.update(junction)
    events = program.events
    move_lines = {mv.line_no for mv in program.moves}
    over, sources = {}, []
    for k, ev in enumerate(events):
        if ev.move_index >= len(program.moves) or ev.line_no in move_lines:
            continue  # after the last move (the end block's own), or on a motion line
        f = fwv.lowered(ev, plan)
        if not f:
            continue
        # homing or probing before the next move runs at the file's value: ours after it
        place = k
        j = k + 1
        while j < len(events) and events[j].move_index == ev.move_index:
            if events[j].name in _HOMING:
                place = j
            j += 1
        over.setdefault(place, {}).update(f)
        sources.append((ev.line_no, ev.name))
    lines = {}
    for k, f in over.items():
        lines.setdefault(events[k].line_no, []).extend(fwv.override_texts(f))
    if not over:
        return None
    raised = {f: v for f, v in junction.items() if any(f in d for d in over.values())}
    ov = AccelOverride(fwv.flavour, ap, at, (ax, ay), over, lines, {}, tuple(sources), raised)
    # what the file has in force at the last move, where ours hold
    mine = raw.overridden(ov)
    last = int(mine.si[-1])
    restore = {}
    for f in plan:
        file_v = raw.snaps[last].get_field(f)
        if file_v != mine.snaps[last].get_field(f):
            restore[f] = file_v
    ov = dataclasses.replace(ov, restore=restore)
    raw.overridden(ov)
    return ov


def override_restore_texts(ov: AccelOverride) -> list[str]:
    """The commands that give the file's own values back after the last move
    (``ov.restore``)."""
    return by_flavour(ov.flavour).override_texts(ov.restore) if ov.restore else []


def as_configured(profile):
    """The profile with the firmware's starting values as the printer is configured
    (``firmware.configured_*``, and the firmware's own junction settings, not the plan's:
    base.plan_junction): what a file runs with until it sets its own. The same profile when
    it states no configuration (the printer runs the profile's values)."""
    fw = profile.firmware
    if _raises_junction(profile):
        profile = firmware_junctions(profile)
    if fw.configured_accel_mm_s2 is None and fw.configured_max_accel_mm_s2 is None:
        return profile
    changes = {}
    if fw.configured_accel_mm_s2 is not None:
        changes.update(accel_mm_s2=fw.configured_accel_mm_s2,
                       travel_accel_mm_s2=fw.configured_accel_mm_s2)
    if fw.configured_max_accel_mm_s2 is not None and firmware_for(profile).axis_max_accel:
        changes["max_accel_mm_s2"] = dict(fw.max_accel_mm_s2, **fw.configured_max_accel_mm_s2)
    return dataclasses.replace(profile, firmware=dataclasses.replace(fw, **changes))


def firmware_junctions(profile):
    """The profile without the hardware's junction limit (``limits.axis_jerk_mm_s``): the
    firmware's and the file's own junction settings hold (base.plan_junction)."""
    if profile.limits.axis_jerk_mm_s is None:
        return profile
    return dataclasses.replace(profile, limits=dataclasses.replace(
        profile.limits, axis_jerk_mm_s=None))


def raises_configured(profile) -> bool:
    """The printer as configured (``firmware.configured_*``) runs lower acceleration limits,
    or a lower junction setting (base.plan_junction), than the plan is timed with: the writer
    sets the plan's (gcode.firmware_lines._PlanLimits)."""
    fw = profile.firmware
    if _raises_junction(profile):
        return True
    if fw.configured_accel_mm_s2 is not None and fw.configured_accel_mm_s2 < max(
            fw.accel_mm_s2, fw.travel_accel_mm_s2):
        return True
    conf = fw.configured_max_accel_mm_s2
    return conf is not None and firmware_for(profile).axis_max_accel and any(
        conf[a] < fw.max_accel_mm_s2[a] for a in ("x", "y"))


def _raises_junction(profile) -> bool:
    """The plan starts at a junction setting above the firmware's (base.plan_junction)."""
    field, key = firmware_for(profile).start_junction
    return plan_junction(profile).get(field, 0.0) > getattr(profile.firmware, key)
