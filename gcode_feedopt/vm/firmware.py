"""Firmware planner models: G-code -> the commanded trajectory the firmware will run, at Ts.

The printer's firmware re-plans every move with its own limits, so the commanded trajectory is
the firmware's. Two models, chosen by the profile's ``firmware.flavour``:

- **Marlin 2**: trapezoidal blocks; per-block acceleration = M204 P (print), T (travel) or
  R (retract), limited per axis by M201 (a·|u_i| ≤ A_i); feed limited per axis by M203; junction
  speed by junction deviation (M205 J; Marlin's formula v² = a·δ·sin(θ/2)/(1 − sin(θ/2)));
  G2/G3 split into chords of ``mm_per_arc_segment`` like Marlin's plan_arc. When the file sets
  classic jerk (M205 X/Y without J, as PrusaSlicer and Cura write for jerk-configured Marlin),
  the junction speed is the highest at which no axis changes speed by more than its jerk.
- **Klipper**: klippy's rules (commit 84104bb; docs/firmware.md): one accel (M204 S, or the
  smaller of M204 P and T; P or T alone, M204 R, M201, M203 and M205 change nothing),
  SET_VELOCITY_LIMIT (VELOCITY, ACCEL, SQUARE_CORNER_VELOCITY, MINIMUM_CRUISE_RATIO), M220 /
  M221; Z and extrude-only limits scaled by the move; junctions at each neighbour's own
  δ·a (δ = scv²(√2 − 1)/accel) and ½·L·a·tan(θ/2), and the extruder's
  instantaneous_corner_velocity; minimum_cruise_ratio's pseudo-accel look-ahead gives a run of
  short moves one reduced peak (plan.trapezoid.klipper_lookahead). Real Klipper times the
  same files to within 1 µs (tests/vm/test_klipper_referee.py).

Both: exact stops at E-only moves, dwells (G4), waits (M400, M109, ...), homing and tool
changes; firmware retraction (G10/G11) takes retract_mm/retract_speed. Settings found in the
file apply from that line on.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from ..plan.trapezoid import (forward_backward, junction_limits, klipper_junction_v2,
                              klipper_lookahead, sample, trapezoids)
from .trajectory import Trajectory

#: Marlin's minimum planner speed (MINIMUM_PLANNER_SPEED), mm/s: junctions never go below it
#: unless the firmware stops there.
MIN_PLANNER_SPEED_MM_S = 0.05


@dataclass
class _Limits:
    accel_print: float
    accel_travel: float
    accel_retract: float
    max_accel: dict
    max_feed: dict
    jd: float
    scv: float
    min_cruise_ratio: float
    velocity: float
    #: classic jerk per axis (M205 X Y Z E) when the file asks for it; None = junction deviation
    jerk: dict | None = None
    #: Klipper's M220 and M221 factors (speed and extrusion; Marlin model: always 1)
    speed_factor: float = 1.0
    extrude_factor: float = 1.0


def _norm3(d) -> float:
    """Length of a 3-vector as √((dx² + dy²) + dz²), written out: the fast block builder
    computes the same expression element-wise, and ``np.linalg.norm`` does not promise that
    order (NumPy 2.4 gives a different last bit), which the bit-identity tests would see."""
    dx, dy, dz = float(d[0]), float(d[1]), float(d[2])
    return math.sqrt((dx * dx + dy * dy) + dz * dz)


def _initial(profile) -> _Limits:
    fw = profile.firmware
    return _Limits(accel_print=fw.accel_mm_s2, accel_travel=fw.travel_accel_mm_s2,
                   accel_retract=fw.accel_mm_s2, max_accel=dict(fw.max_accel_mm_s2),
                   max_feed=dict(fw.max_feed_mm_s), jd=fw.junction_deviation_mm,
                   scv=fw.square_corner_velocity_mm_s,
                   min_cruise_ratio=fw.minimum_cruise_ratio,
                   velocity=max(fw.max_feed_mm_s["x"], fw.max_feed_mm_s["y"]))


def _apply_event(lim: _Limits, ev, klipper: bool) -> None:
    if klipper:
        _apply_event_klipper(lim, ev)
        return
    p = ev.params
    n = ev.name
    if n == "M204":
        if "S" in p:
            lim.accel_print = lim.accel_travel = float(p["S"])
        if "P" in p:
            lim.accel_print = float(p["P"])
        if "T" in p:
            lim.accel_travel = float(p["T"])
        if "R" in p:
            lim.accel_retract = float(p["R"])
    elif n == "M201":
        for L in "XYZE":
            if L in p:
                lim.max_accel[L.lower()] = float(p[L])
    elif n == "M203":
        for L in "XYZE":
            if L in p:
                lim.max_feed[L.lower()] = float(p[L])
    elif n == "M205":
        if "J" in p:
            lim.jd = float(p["J"])
            lim.jerk = None
        elif any(L in p for L in "XY"):
            # the slicer configured classic jerk (Prusa, many Creality builds): model it
            j = dict(lim.jerk or {"x": 10.0, "y": 10.0, "z": 0.3, "e": 5.0})
            for L in "XYZE":
                if L in p:
                    j[L.lower()] = float(p[L])
            lim.jerk = j
    elif n == "SET_VELOCITY_LIMIT":
        # not a Marlin command; kept from the first model (docs/firmware.md: not followed)
        if isinstance(p.get("VELOCITY"), float):
            lim.velocity = p["VELOCITY"]
        if isinstance(p.get("ACCEL"), float):
            lim.accel_print = lim.accel_travel = p["ACCEL"]
        if isinstance(p.get("SQUARE_CORNER_VELOCITY"), float):
            lim.scv = p["SQUARE_CORNER_VELOCITY"]
        if isinstance(p.get("MINIMUM_CRUISE_RATIO"), float):
            lim.min_cruise_ratio = p["MINIMUM_CRUISE_RATIO"]
        if isinstance(p.get("ACCEL_TO_DECEL"), float) and lim.accel_print > 0:
            lim.min_cruise_ratio = max(0.0, 1.0 - p["ACCEL_TO_DECEL"] / lim.accel_print)


def _positive(p: dict, key: str) -> float | None:
    v = p.get(key)
    return float(v) if isinstance(v, float) and v > 0 else None


def _klipper_accel_set(ev) -> float | None:
    """The accel a line sets in Klipper (``M204 S``, the smaller of ``M204 P T``,
    ``SET_VELOCITY_LIMIT ACCEL``), or None: it sets none (or Klipper refuses it)."""
    p = ev.params
    if ev.name == "M204":
        a = _positive(p, "S")
        if a is None:
            pa, ta = _positive(p, "P"), _positive(p, "T")
            a = None if pa is None or ta is None else min(pa, ta)
        return a
    if ev.name == "SET_VELOCITY_LIMIT":
        return _positive(p, "ACCEL")
    return None


def _apply_event_klipper(lim: _Limits, ev) -> None:
    """Klipper's commands that change the motion (klippy toolhead.py and gcode_move.py):
    ``M204 S`` sets the one acceleration, or ``M204 P.. T..`` the smaller of the two (P or T
    alone is refused: nothing changes); SET_VELOCITY_LIMIT VELOCITY / ACCEL /
    SQUARE_CORNER_VELOCITY / MINIMUM_CRUISE_RATIO; M220 / M221 the speed and extrusion
    factors. M201, M203, M205 and M204 R are not Klipper commands: ignored. Both accels of
    ``_Limits`` hold the one accel."""
    p = ev.params
    n = ev.name
    a = _klipper_accel_set(ev)
    if a is not None:
        lim.accel_print = lim.accel_travel = a
    if n == "SET_VELOCITY_LIMIT":
        if _positive(p, "VELOCITY") is not None:
            lim.velocity = p["VELOCITY"]
        v = p.get("SQUARE_CORNER_VELOCITY")
        if isinstance(v, float) and v >= 0:
            lim.scv = v
        v = p.get("MINIMUM_CRUISE_RATIO")
        if isinstance(v, float) and 0 <= v < 1:
            lim.min_cruise_ratio = v
    elif n in ("M220", "M221") and ("S" not in p or _positive(p, "S") is not None):
        f = p.get("S", 100.0) / 100.0
        if n == "M220":
            lim.speed_factor = f
        else:
            lim.extrude_factor = f


#: ``--accel``: ``plan`` — the plan's accelerations (the profile's, within the machine's hardware
#: limits) override lower ones the file sets; ``file`` — the file's own are kept
ACCELS = ("plan", "file")

#: commands that home or probe: a file lowers the acceleration for them on purpose (PrusaSlicer's
#: MINI start block: ``M204 T1250`` before G28/G29, sensorless homing), so a lowering followed
#: by one of them before the next move is kept
_HOMING = frozenset({"G28", "G29", "G30", "G34", "M48", "BED_MESH_CALIBRATE", "PROBE",
                     "QUAD_GANTRY_LEVEL", "Z_TILT_ADJUST", "SCREWS_TILT_CALCULATE"})


@dataclass(frozen=True)
class AccelOverride:
    """The plan's accelerations over the file's (``--accel plan``), for one program.

    ``events``: event index -> {field: the plan's value} for every line of the file that sets
    an acceleration below the plan's (fields of ``_Limits``: ``accel_print`` (M204 P, S),
    ``accel_travel`` (M204 T, S), ``x``, ``y`` (M201 X Y); Klipper's one accel is both
    accels), keyed by the event after which they apply: the file's line itself, or the last
    homing or probing command before the next move (the file lowers accelerations for homing on
    purpose: those run at its values). The settings replay (``_limit_snapshots`` and the
    references) applies them there, as the writer's lines after that line (``lines``: line
    number -> the commands it adds) make the firmware do. ``restore``: the file's own values in force at the
    last move where the plan's hold there, {field: value} (the writer gives them back after
    the last move). M204 R, M201 Z and E and the junction settings (M205, square corner
    velocity) stay the file's."""

    flavour: str
    accel_print_mm_s2: float
    accel_travel_mm_s2: float
    max_accel_xy_mm_s2: tuple
    events: dict
    lines: dict
    restore: dict
    #: (line number, command) of every line of the file whose acceleration is overridden
    sources: tuple = ()

    @property
    def n_lines(self) -> int:
        return sum(len(v) for v in self.lines.values())


def plan_accels(profile) -> tuple[float, float, tuple]:
    """(M204 P, M204 T, (M201 X, Y)) the plan runs at: the profile's firmware values within the
    machine's hardware limits (``limits.amax_mm_s2``, ``limits.axis_amax_mm_s2``); Klipper's
    one accel within both axes' limits."""
    fw, lim = profile.firmware, profile.limits
    xy = tuple(min(lim.axis_amax_mm_s2[a], lim.amax_mm_s2, fw.max_accel_mm_s2[a]) for a in "xy")
    if fw.flavour == "klipper":
        a = min(fw.accel_mm_s2, *xy)
        return a, a, xy
    return min(fw.accel_mm_s2, lim.amax_mm_s2), min(fw.travel_accel_mm_s2, lim.amax_mm_s2), xy


def _lowered(ev, plan: dict, klipper: bool) -> dict:
    """{field: the plan's value} of the accelerations ``ev`` sets below the plan's."""
    p, n = ev.params, ev.name
    vals = {}
    if klipper:
        a = _klipper_accel_set(ev)
        if a is not None:
            vals = {"accel_print": a, "accel_travel": a}
    elif n == "M204":
        for key, fields in (("S", ("accel_print", "accel_travel")), ("P", ("accel_print",)),
                            ("T", ("accel_travel",))):
            if isinstance(p.get(key), float):
                vals.update({f: p[key] for f in fields})
    elif n == "M201":
        vals = {L.lower(): p[L] for L in "XY" if isinstance(p.get(L), float)}
    elif n == "SET_VELOCITY_LIMIT" and isinstance(p.get("ACCEL"), float):
        vals = {"accel_print": p["ACCEL"], "accel_travel": p["ACCEL"]}
    return {f: plan[f] for f, v in vals.items() if v < plan[f]}


def _set_fields(lim: _Limits, fields: dict) -> None:
    for f, v in fields.items():
        if f in ("x", "y"):
            lim.max_accel[f] = v
        else:
            setattr(lim, f, v)


def accel_override(program, profile, policy: str = "plan") -> AccelOverride | None:
    """:class:`AccelOverride` of ``program`` under ``policy`` (:data:`ACCELS`), or None: the
    file's own accelerations hold (``file``, or no line of the file sets one below the plan's
    before a move)."""
    if policy not in ACCELS:
        raise ValueError(f"unknown acceleration policy {policy!r}; use one of {', '.join(ACCELS)}")
    if policy == "file" or not program.moves:
        return None
    klipper = profile.firmware.flavour == "klipper"
    ap, at, (ax, ay) = plan_accels(profile)
    plan = {"accel_print": ap, "accel_travel": at, "x": ax, "y": ay}
    events = program.events
    move_lines = {mv.line_no for mv in program.moves}
    over, sources = {}, []
    for k, ev in enumerate(events):
        if ev.move_index >= len(program.moves) or ev.line_no in move_lines:
            continue  # after the last move (the end block's own), or on a motion line
        f = _lowered(ev, plan, klipper)
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
        lines.setdefault(events[k].line_no, []).extend(_override_texts(f, klipper))
    if not over:
        return None
    ov = AccelOverride("klipper" if klipper else "marlin", ap, at, (ax, ay), over, lines, {},
                       tuple(sources))
    # what the file has in force at the last move, where ours hold
    raw, _ = _limit_snapshots(program, profile, klipper)
    mine, si = _limit_snapshots(program, profile, klipper, ov)
    last = int(si[-1])
    restore = {}
    for f in ("accel_print", "accel_travel", "x", "y"):
        get = (lambda q: q.max_accel[f]) if f in ("x", "y") else (lambda q: getattr(q, f))
        if get(raw[last]) != get(mine[last]):
            restore[f] = get(raw[last])
    return dataclasses.replace(ov, restore=restore)


def _override_texts(fields: dict, klipper: bool) -> list[str]:
    """The commands that set ``fields`` ({field: value}, :class:`AccelOverride`): Marlin
    ``M204 P.. T..`` and ``M201 X.. Y..`` (those of them it sets), Klipper
    ``SET_VELOCITY_LIMIT ACCEL=..``."""
    def g(v):
        return f"{v:.3f}".rstrip("0").rstrip(".")
    if klipper:
        return [f"SET_VELOCITY_LIMIT ACCEL={g(fields.get('accel_print', fields.get('accel_travel')))}"]
    out = []
    pt = [f"{L}{g(fields[f])}" for L, f in (("P", "accel_print"), ("T", "accel_travel"))
          if f in fields]
    if pt:
        out.append("M204 " + " ".join(pt))
    xy = [f"{L}{g(fields[L.lower()])}" for L in "XY" if L.lower() in fields]
    if xy:
        out.append("M201 " + " ".join(xy))
    return out


def override_restore_texts(ov: AccelOverride) -> list[str]:
    """The commands that give the file's own values back after the last move
    (``ov.restore``)."""
    return _override_texts(ov.restore, ov.flavour == "klipper") if ov.restore else []


@dataclass(frozen=True)
class Blocks:
    """The firmware's planner blocks (N): straight pieces in XYZ+E.

    start_mm (N,3), end_mm (N,3), e0_mm (N,), de_mm (N,), length_mm (N,) (XYZ length, or |ΔE|
    for E-only blocks; Klipper: |ΔE| × M221), accel (N,), peak_accel (N,) (Klipper: the
    pseudo-accel of minimum_cruise_ratio; Marlin: accel), vcap (N,), stop_after (N,),
    dwell_after_s (N,), lead_s; ``jd`` (N,) the junction deviation of each block (Klipper: from
    square_corner_velocity and the toolhead's accel), ``turn_cos`` (N-1,) per junction."""

    start_mm: np.ndarray
    end_mm: np.ndarray
    e0_mm: np.ndarray
    de_mm: np.ndarray
    length_mm: np.ndarray
    accel: np.ndarray
    peak_accel: np.ndarray
    vcap: np.ndarray
    stop_after: np.ndarray
    dwell_after_s: np.ndarray
    jd: np.ndarray
    turn_cos: np.ndarray
    lead_s: float
    klipper: bool
    #: (N-1,) classic-jerk junction limit (inf where junction deviation applies)
    jerk_v: np.ndarray | None = None
    #: Klipper: (N,) the extruder's share of each block, dE/L (dE × M221), whose change at a
    #: junction is held to ``icv_mm_s`` (instantaneous_corner_velocity); None for Marlin
    e_ratio: np.ndarray | None = None
    icv_mm_s: float = 1.0


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


def move_limits(program, profile, fast: bool = True,
                override: AccelOverride | None = None) -> MoveLimits:
    """What the firmware will allow for each move, honouring the settings found in the file, so
    a planner can stay within them (the firmware would otherwise run our plan slower).

    ``fast``: the limits looked up per move from one snapshot per event (bit-identical to
    ``False``, the reference that applies the events move by move). ``override``
    (:func:`accel_override`): the plan's accelerations where the file's lines lower them."""
    if not fast:
        return _move_limits_reference(program, profile, override)
    klipper = profile.firmware.flavour == "klipper"
    snaps, si = _limit_snapshots(program, profile, klipper, override)
    moves = program.moves
    de = (np.array([mv.e_end_mm for mv in moves], dtype=float)
          - np.array([mv.e_start_mm for mv in moves], dtype=float))
    acc = np.where(de > 0, np.array([q.accel_print for q in snaps])[si],
                   np.array([q.accel_travel for q in snaps])[si])
    macc = np.array([[q.max_accel[k] for k in "xyz"] for q in snaps]).reshape(-1, 3)[si]
    mfeed = np.array([[q.max_feed[k] for k in "xyz"] for q in snaps]).reshape(-1, 3)[si]
    if klipper:
        jd = np.array([q.scv ** 2 * (math.sqrt(2) - 1) for q in snaps])[si] / acc
        vel = np.array([q.velocity for q in snaps])[si]
    else:
        jd = np.array([q.jd for q in snaps])[si]
        vel = np.full(len(moves), np.inf)
    jerk = np.array([[np.nan] * 3 if q.jerk is None else [q.jerk[k] for k in "xyz"]
                     for q in snaps]).reshape(-1, 3)[si]
    e_acc = np.array([_e_only_accel(q, klipper) for q in snaps])[si]
    e_feed = np.array([q.max_feed["e"] for q in snaps], dtype=float)[si]
    mcr = np.array([q.min_cruise_ratio if klipper else 0.0 for q in snaps])[si]
    ef = np.array([q.extrude_factor for q in snaps])[si]
    return MoveLimits(acc, macc, mfeed, jd, jerk, vel, e_acc, e_feed, mcr, ef)


def _e_only_accel(lim: _Limits, klipper: bool) -> float:
    """An E-only move's accel: Klipper's max_extrude_only_accel; Marlin's M204 R within
    M201 E."""
    return lim.max_accel["e"] if klipper else min(lim.accel_retract, lim.max_accel["e"])


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


def as_configured(profile):
    """The profile with the firmware's starting values as the printer is configured
    (``firmware.configured_*``): what a file runs with until it sets its own. The same
    profile when it states no configuration (the printer runs the profile's values)."""
    fw = profile.firmware
    if fw.configured_accel_mm_s2 is None and fw.configured_max_accel_mm_s2 is None:
        return profile
    changes = {}
    if fw.configured_accel_mm_s2 is not None:
        changes.update(accel_mm_s2=fw.configured_accel_mm_s2,
                       travel_accel_mm_s2=fw.configured_accel_mm_s2)
    if fw.configured_max_accel_mm_s2 is not None and fw.flavour != "klipper":
        changes["max_accel_mm_s2"] = dict(fw.max_accel_mm_s2, **fw.configured_max_accel_mm_s2)
    return dataclasses.replace(profile, firmware=dataclasses.replace(fw, **changes))


def raises_configured(profile) -> bool:
    """The printer as configured (``firmware.configured_*``) runs lower acceleration limits
    than the plan is timed with: the writer sets the plan's (gcode.firmware_lines._PlanLimits)."""
    fw = profile.firmware
    if fw.configured_accel_mm_s2 is not None and fw.configured_accel_mm_s2 < max(
            fw.accel_mm_s2, fw.travel_accel_mm_s2):
        return True
    conf = fw.configured_max_accel_mm_s2
    return conf is not None and fw.flavour != "klipper" and any(
        conf[a] < fw.max_accel_mm_s2[a] for a in ("x", "y"))


def accel_settings(program, profile, clamp=None,
                   override: AccelOverride | None = None) -> AccelSettings:
    """:class:`AccelSettings` of ``program`` (the profile's, then the file's own settings); with
    a Klipper :class:`AccelClamp`, its one accel as clamped to the plan's limits (what a writer
    restores after a slowed stretch is then the clamped value); with ``override``, the plan's
    accelerations where the file's lines lower them (what the writer's lines leave in force)."""
    klipper = profile.firmware.flavour == "klipper"
    snaps, si = _limit_snapshots(program, profile, klipper, override)
    jerk = np.array([[np.nan] * 2 if q.jerk is None or klipper else [q.jerk["x"], q.jerk["y"]]
                     for q in snaps]).reshape(-1, 2)
    acc_p = np.array([q.accel_print for q in snaps])[si]
    acc_t = np.array([q.accel_travel for q in snaps])[si]
    if clamp is not None and klipper:
        acc_p = np.minimum(acc_p, clamp.want_mm_s2[:, 0])
        acc_t = np.minimum(acc_t, clamp.want_mm_s2[:, 0])
    macc = np.array([[q.max_accel["x"], q.max_accel["y"]] for q in snaps]).reshape(-1, 2)[si]
    return AccelSettings(profile.firmware.flavour, acc_p, acc_t, jerk[si],
                         np.array([q.scv for q in snaps])[si], macc,
                         np.array([q.accel_retract for q in snaps])[si])


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


def accel_clamp(program, profile, axis_amax_mm_s2: dict,
                override: AccelOverride | None = None) -> AccelClamp | None:
    """:class:`AccelClamp` of ``program`` under the plan's axis limits (plan.kinematic
    .effective_limits), or None when the file's settings are never above them. The file's
    values are those in force with ``override`` (the writer's lines over the file's)."""
    klipper = profile.firmware.flavour == "klipper"
    snaps, si = _limit_snapshots(program, profile, klipper, override)
    if klipper:
        file = np.array([[q.accel_print] for q in snaps], dtype=float).reshape(-1, 1)
        cap = np.array([min(axis_amax_mm_s2["x"], axis_amax_mm_s2["y"])])
        sets = [_klipper_accel_set(ev) is not None for ev in program.events]
    else:
        file = np.array([[q.max_accel[k] for k in "xyz"] for q in snaps],
                        dtype=float).reshape(-1, 3)
        cap = np.array([axis_amax_mm_s2[k] for k in "xyz"], dtype=float)
        sets = [ev.name == "M201" for ev in program.events]
    if not len(program.moves) or not np.any(file[np.unique(si)] > cap):
        return None
    ev_mi = np.array([ev.move_index for ev, hit in zip(program.events, sets) if hit],
                     dtype=np.int64)
    epoch = np.searchsorted(ev_mi, np.arange(len(program.moves)), side="right")
    return AccelClamp("klipper" if klipper else "marlin", file[si], np.minimum(file[si], cap),
                      epoch)


def _limit_snapshots(program, profile, klipper: bool, override: AccelOverride | None = None):
    """The limits in force after each event (``snaps``: E+1, the first before any event) and,
    (M,) per move, the index of the snapshot in force at it (after every event read before
    it). The file sets limits a few thousand times at most; a move looks its limits up.
    ``override``: the plan's accelerations over the file's lines that lower them."""
    lim = _initial(profile)
    snaps = [_snapshot(lim)]
    over = override.events if override is not None else {}
    for k, ev in enumerate(program.events):
        _apply_event(lim, ev, klipper)
        if k in over:
            _set_fields(lim, over[k])
        snaps.append(_snapshot(lim))
    ev_mi = np.array([ev.move_index for ev in program.events], dtype=np.int64)
    si = np.searchsorted(ev_mi, np.arange(len(program.moves)), side="right")
    return snaps, si


def _snapshot(lim: _Limits) -> _Limits:
    return _Limits(lim.accel_print, lim.accel_travel, lim.accel_retract, dict(lim.max_accel),
                   dict(lim.max_feed), lim.jd, lim.scv, lim.min_cruise_ratio, lim.velocity,
                   None if lim.jerk is None else dict(lim.jerk), lim.speed_factor,
                   lim.extrude_factor)


def _move_limits_reference(program, profile, override=None) -> MoveLimits:
    """:func:`move_limits` move by move."""
    klipper = profile.firmware.flavour == "klipper"
    lim = _initial(profile)
    events = program.events
    over = override.events if override is not None else {}
    ei = 0
    m = len(program.moves)
    acc = np.empty(m)
    macc = np.empty((m, 3))
    mfeed = np.empty((m, 3))
    jd = np.empty(m)
    jerk = np.full((m, 3), np.nan)
    vel = np.full(m, np.inf)
    e_acc = np.empty(m)
    e_feed = np.empty(m)
    mcr = np.empty(m)
    ef = np.empty(m)
    for mi, mv in enumerate(program.moves):
        while ei < len(events) and events[ei].move_index <= mi:
            _apply_event(lim, events[ei], klipper)
            if ei in over:
                _set_fields(lim, over[ei])
            ei += 1
        a = lim.accel_print if mv.de_mm > 0 else lim.accel_travel
        acc[mi] = a
        macc[mi] = [lim.max_accel[k] for k in "xyz"]
        mfeed[mi] = [lim.max_feed[k] for k in "xyz"]
        jd[mi] = lim.scv ** 2 * (math.sqrt(2) - 1) / a if klipper else lim.jd
        if lim.jerk is not None:
            jerk[mi] = [lim.jerk[k] for k in "xyz"]
        if klipper:
            vel[mi] = lim.velocity
        e_acc[mi] = _e_only_accel(lim, klipper)
        e_feed[mi] = lim.max_feed["e"]
        mcr[mi] = lim.min_cruise_ratio if klipper else 0.0
        ef[mi] = lim.extrude_factor
    return MoveLimits(acc, macc, mfeed, jd, jerk, vel, e_acc, e_feed, mcr, ef)


#: √2 − 1: Klipper's junction deviation is square_corner_velocity² (√2 − 1) / max_accel
_SCV_JD = math.sqrt(2) - 1


def _klipper_move(lim: _Limits, d, L: float, de: float, feed: float):
    """Klipper's limits of one move in XYZ (klippy's toolhead Move with the cartesian and
    extruder checks): (accel, minimum_cruise_ratio's pseudo-accel, speed cap, junction
    deviation, extruder ratio dE/L).

    The one accel (max_accel as set by M204 / SET_VELOCITY_LIMIT) and F × M220 within
    max_velocity; a move with Z within max_z_velocity and max_z_accel scaled by L/|dZ|; a move
    that retracts, or extrudes without X/Y, within the extrude-only limits scaled by L/|dE|
    (dE × M221); the pseudo-accel max_accel × (1 − minimum_cruise_ratio), never above the
    move's own accel; the junction deviation from the toolhead's accel, not the move's."""
    a = lim.accel_print
    v = min(feed * lim.speed_factor, lim.velocity)
    dz = float(d[2])
    if dz != 0.0:
        zr = L / abs(dz)
        v = min(v, lim.max_feed["z"] * zr)
        a = min(a, lim.max_accel["z"] * zr)
    er = de * lim.extrude_factor / L
    if de != 0.0 and ((float(d[0]) == 0.0 and float(d[1]) == 0.0) or er < 0.0):
        inv = 1.0 / abs(er)
        v = min(v, lim.max_feed["e"] * inv)
        a = min(a, lim.max_accel["e"] * inv)
    peak_a = min(a, lim.accel_print * (1.0 - lim.min_cruise_ratio))
    jd = lim.scv ** 2 * _SCV_JD / lim.accel_print
    return a, peak_a, v, jd, er


def _klipper_e_only(lim: _Limits, de: float, feed: float):
    """Klipper's E-only move: (length |dE| × M221, accel, pseudo-accel, speed cap, junction
    deviation): the extrude-only limits; F × M220 not capped by max_velocity."""
    a = lim.max_accel["e"]
    return (abs(de) * lim.extrude_factor, a,
            min(a, lim.accel_print * (1.0 - lim.min_cruise_ratio)),
            min(feed * lim.speed_factor, lim.max_feed["e"]),
            lim.scv ** 2 * _SCV_JD / lim.accel_print)


def build_blocks(program, profile, fast: bool = True,
                 override: AccelOverride | None = None) -> Blocks:
    """Split the program into the firmware's planner blocks with the limits in force.

    ``fast``: straight moves as arrays (:func:`_build_blocks_fast`); ``False``: every move
    one by one (:func:`_build_blocks_reference`, the reference the fast path is tested against:
    the same blocks, bit for bit). ``override`` (:func:`accel_override`): the program as if
    each file line lowering an acceleration were followed by the writer's line raising it (the
    input timed at the plan's accelerations)."""
    if fast:
        return _build_blocks_fast(program, profile, override)
    return _build_blocks_reference(program, profile, override)


def _build_blocks_reference(program, profile, override=None) -> Blocks:
    """:func:`build_blocks` move by move."""
    fw = profile.firmware
    klipper = fw.flavour == "klipper"
    lim = _initial(profile)
    events = program.events
    over = override.events if override is not None else {}
    ei = 0
    rows = []  # (start, end, e0, de, L, accel, peak_accel, vcap, jd, eonly)
    stop_idx: dict[int, float] = {}
    lead = 0.0

    def stop(dwell):
        nonlocal lead
        if rows:
            k = len(rows) - 1
            stop_idx[k] = stop_idx.get(k, 0.0) + dwell
        else:
            lead += dwell

    for mi, mv in enumerate(program.moves):
        while ei < len(events) and events[ei].move_index <= mi:
            ev = events[ei]
            _apply_event(lim, ev, klipper)
            if ei in over:
                _set_fields(lim, over[ei])
            if ev.stop:
                stop(ev.dwell_s)
            ei += 1
        feed = mv.feed_mm_s
        pts = [np.asarray(mv.start_mm, float)]
        if mv.arc is not None:
            arc = mv.arc
            planar = abs(arc.sweep_rad) * arc.radius_mm
            nseg = _arc_segments(planar, mv.end_mm[2] - mv.start_mm[2], fw, klipper)
            th0 = math.atan2(mv.start_mm[1] - arc.center_mm[1], mv.start_mm[0] - arc.center_mm[0])
            for j in range(1, nseg + 1):
                u = j / nseg
                th = th0 + arc.sweep_rad * u
                pts.append(np.array([arc.center_mm[0] + arc.radius_mm * math.cos(th),
                                     arc.center_mm[1] + arc.radius_mm * math.sin(th),
                                     mv.start_mm[2] + (mv.end_mm[2] - mv.start_mm[2]) * u]))
            pts[-1] = np.asarray(mv.end_mm, float)
        else:
            pts.append(np.asarray(mv.end_mm, float))
        total = sum(_norm3(pts[j + 1] - pts[j]) for j in range(len(pts) - 1))
        de_total = mv.de_mm
        if total <= 1e-9:
            if abs(de_total) <= 1e-12:
                continue
            # E-only block: a stop on both sides
            if klipper:
                L, a, peak_a, v, jd = _klipper_e_only(lim, de_total, feed)
            else:
                L, v, jd = abs(de_total), min(feed, lim.max_feed["e"]), lim.jd
                a = peak_a = min(lim.accel_retract, lim.max_accel["e"])
            if rows:
                stop(0.0)
            rows.append((pts[0], pts[0], mv.e_start_mm, de_total, L, a, peak_a, v, jd, True,
                         lim.jerk, 0.0))
            stop(0.0)
            continue
        e0 = mv.e_start_mm
        extruding = de_total > 0
        base_a = lim.accel_print if extruding else lim.accel_travel
        for j in range(len(pts) - 1):
            d = pts[j + 1] - pts[j]
            L = _norm3(d)
            if L <= 1e-12:
                continue
            de = de_total * L / total
            if klipper:
                a, peak_a, v, jd, er = _klipper_move(lim, d, L, de, feed)
                rows.append((pts[j], pts[j + 1], e0, de, L, a, peak_a, v, jd, False, None, er))
                e0 += de
                continue
            u = np.abs(d) / L
            # per-axis caps (E too: its speed is de/L times the path speed)
            ue = abs(de) / L
            a = base_a
            v = feed
            for k, ax in enumerate("xyz"):
                if u[k] > 1e-12:
                    a = min(a, lim.max_accel[ax] / u[k])
                    v = min(v, lim.max_feed[ax] / u[k])
            if ue > 1e-12:
                a = min(a, lim.max_accel["e"] / ue)
                v = min(v, lim.max_feed["e"] / ue)
            rows.append((pts[j], pts[j + 1], e0, de, L, a, a, v, lim.jd, False, lim.jerk, 0.0))
            e0 += de
    while ei < len(events):
        if events[ei].stop:
            stop(events[ei].dwell_s)
        ei += 1
    n = len(rows)
    if n == 0:
        z = np.zeros(0)
        return Blocks(np.zeros((0, 3)), np.zeros((0, 3)), z, z, z, z, z, z, np.zeros(0, bool), z,
                      z, z, lead, klipper)
    start = np.array([r[0] for r in rows])
    end = np.array([r[1] for r in rows])
    e0 = np.array([r[2] for r in rows])
    de = np.array([r[3] for r in rows])
    L = np.array([r[4] for r in rows])
    acc = np.array([r[5] for r in rows])
    peak = np.array([r[6] for r in rows])
    vcap = np.array([r[7] for r in rows])
    jd = np.array([r[8] for r in rows])
    eonly = np.array([r[9] for r in rows])
    e_ratio = np.array([r[11] for r in rows])
    stop_after = np.zeros(n, bool)
    dwell = np.zeros(n)
    for k, dw in stop_idx.items():
        stop_after[k] = True
        dwell[k] = dw
    stop_after[-1] = True
    stop_after |= eonly
    d = end - start
    nrm = np.linalg.norm(d, axis=1, keepdims=True)
    unit = np.where(nrm > 0, d / np.where(nrm > 0, nrm, 1), 0.0)
    turn = np.einsum("ij,ij->i", unit[:-1], unit[1:])
    # E-only neighbours: stop (handled by stop_after); give them a reversal so no speed carries
    turn = np.where(eonly[:-1] | eonly[1:], -1.0, turn)
    jerk_v = np.full(max(n - 1, 0), np.inf)
    for k in range(n - 1):
        jk = rows[k + 1][10]
        if jk is None:
            continue
        dv = np.abs(unit[k + 1] - unit[k])
        lim_v = np.inf
        for a_i, ax in enumerate("xyz"):
            if dv[a_i] > 1e-12:
                lim_v = min(lim_v, jk[ax] / dv[a_i])
        jerk_v[k] = lim_v
    return Blocks(start, end, e0, de, L, acc, peak, vcap, stop_after, dwell, jd, turn, lead, klipper,
                  jerk_v, e_ratio if klipper else None, fw.instantaneous_corner_velocity_mm_s)


def _arc_segments(planar_mm: float, dz_mm: float, fw, klipper: bool) -> int:
    """Chords of an arc: Marlin's ceil(planar length / mm_per_arc_segment); Klipper's
    [gcode_arcs] floor(helix length / resolution) (at least one)."""
    if klipper:
        return max(1, int(math.floor(math.hypot(planar_mm, dz_mm) / fw.mm_per_arc_segment)))
    return max(1, int(math.ceil(planar_mm / fw.mm_per_arc_segment)))


def _arc_rows(mv, lim: _Limits, fw, klipper: bool, feed: float):
    """The chords of one arc move as rows of :func:`_build_blocks_reference` (its code for
    arcs, unchanged), or None where the arc is too short to move (never for real arcs; the
    caller then falls back to the reference)."""
    arc = mv.arc
    pts = [np.asarray(mv.start_mm, float)]
    planar = abs(arc.sweep_rad) * arc.radius_mm
    nseg = _arc_segments(planar, mv.end_mm[2] - mv.start_mm[2], fw, klipper)
    th0 = math.atan2(mv.start_mm[1] - arc.center_mm[1], mv.start_mm[0] - arc.center_mm[0])
    for j in range(1, nseg + 1):
        u = j / nseg
        th = th0 + arc.sweep_rad * u
        pts.append(np.array([arc.center_mm[0] + arc.radius_mm * math.cos(th),
                             arc.center_mm[1] + arc.radius_mm * math.sin(th),
                             mv.start_mm[2] + (mv.end_mm[2] - mv.start_mm[2]) * u]))
    pts[-1] = np.asarray(mv.end_mm, float)
    total = sum(_norm3(pts[j + 1] - pts[j]) for j in range(len(pts) - 1))
    if total <= 1e-9:
        return None
    de_total = mv.de_mm
    e0 = mv.e_start_mm
    base_a = lim.accel_print if de_total > 0 else lim.accel_travel
    rows = []
    for j in range(len(pts) - 1):
        d = pts[j + 1] - pts[j]
        L = _norm3(d)
        if L <= 1e-12:
            continue
        de = de_total * L / total
        if klipper:
            a, peak_a, v, jd, er = _klipper_move(lim, d, L, de, feed)
            rows.append((pts[j], pts[j + 1], e0, de, L, a, peak_a, v, jd, False, None, er))
            e0 += de
            continue
        u = np.abs(d) / L
        ue = abs(de) / L
        a = base_a
        v = feed
        for k, ax in enumerate("xyz"):
            if u[k] > 1e-12:
                a = min(a, lim.max_accel[ax] / u[k])
                v = min(v, lim.max_feed[ax] / u[k])
        if ue > 1e-12:
            a = min(a, lim.max_accel["e"] / ue)
            v = min(v, lim.max_feed["e"] / ue)
        rows.append((pts[j], pts[j + 1], e0, de, L, a, a, v, lim.jd, False, lim.jerk, 0.0))
        e0 += de
    return rows


def _build_blocks_fast(program, profile, override=None) -> Blocks:
    """:func:`build_blocks` with straight moves as arrays.

    The limits in force are taken once per event (a snapshot after each) and looked up per
    move; a straight move is one block whose length, caps and accelerations are computed
    element-wise with the reference's operations in the same order (the length as
    √((dx² + dy²) + dz²), :func:`_norm3`), so the blocks are bit-identical. Arcs (rare: chords) go through the reference's code."""
    fw = profile.firmware
    klipper = fw.flavour == "klipper"
    moves = program.moves
    events = program.events
    m = len(moves)
    snaps, si = _limit_snapshots(program, profile, klipper, override)
    macc = np.array([[q.max_accel[k] for k in "xyze"] for q in snaps])[si]
    mfeed = np.array([[q.max_feed[k] for k in "xyze"] for q in snaps])[si]
    start = np.array([mv.start_mm for mv in moves], dtype=float).reshape(m, 3)
    end = np.array([mv.end_mm for mv in moves], dtype=float).reshape(m, 3)
    e_start = np.array([mv.e_start_mm for mv in moves], dtype=float)
    de_total = np.array([mv.e_end_mm for mv in moves], dtype=float) - e_start
    feed = np.array([mv.feed_mm_s for mv in moves], dtype=float)
    is_arc = np.array([mv.arc is not None for mv in moves], dtype=bool)
    d = end - start
    total = np.sqrt((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2])
    still = total <= 1e-9
    eonly = ~is_arc & still & (np.abs(de_total) > 1e-12)
    line = ~is_arc & ~still
    # chords of the arcs, in the reference's code
    arc_rows = {}
    for mi in np.flatnonzero(is_arc):
        q = snaps[si[mi]]
        rows = _arc_rows(moves[mi], q, fw, klipper, float(feed[mi]))
        if rows is None:
            return _build_blocks_reference(program, profile, override)
        arc_rows[int(mi)] = rows
    count = (line | eonly).astype(np.int64)
    for mi, rows in arc_rows.items():
        count[mi] = len(rows)
    rows_before = np.concatenate([[0], np.cumsum(count)])
    n = int(rows_before[-1])
    lead = 0.0
    if n == 0:
        for ev in events:
            if ev.stop:
                lead += ev.dwell_s
        z = np.zeros(0)
        return Blocks(np.zeros((0, 3)), np.zeros((0, 3)), z, z, z, z, z, z, np.zeros(0, bool), z,
                      z, z, lead, klipper)
    b_start = np.empty((n, 3))
    b_end = np.empty((n, 3))
    b_e0 = np.empty(n)
    b_de = np.empty(n)
    b_L = np.empty(n)
    b_acc = np.empty(n)
    b_peak = np.empty(n)
    b_vcap = np.empty(n)
    b_jd = np.empty(n)
    b_eonly = np.zeros(n, bool)
    b_jerk = np.full((n, 3), np.nan)  # NaN: junction deviation applies at this block
    b_er = np.zeros(n)

    # straight moves: one block each; E-only moves: one block each, a stop on both sides
    li = np.flatnonzero(line)
    ei_ = np.flatnonzero(eonly)
    for idx in (li, ei_):
        r = rows_before[idx]
        b_start[r] = start[idx]
        b_e0[r] = e_start[idx]
    b_end[rows_before[li]] = end[li]
    b_end[rows_before[ei_]] = start[ei_]
    b_eonly[rows_before[ei_]] = True
    if klipper:
        _klipper_fast(snaps, si, li, ei_, rows_before[li], rows_before[ei_], d[li], total[li],
                      de_total, feed, macc, mfeed, b_de, b_L, b_acc, b_peak, b_vcap, b_jd, b_er)
    else:
        _marlin_fast(snaps, si, li, ei_, rows_before[li], rows_before[ei_], d[li], total[li],
                     de_total, feed, macc, mfeed, b_de, b_L, b_acc, b_peak, b_vcap, b_jd)
        snap_jerk = np.array([[np.nan] * 3 if q.jerk is None else [q.jerk[k] for k in "xyz"]
                              for q in snaps])
        b_jerk[rows_before[li]] = snap_jerk[si[li]]
        b_jerk[rows_before[ei_]] = snap_jerk[si[ei_]]

    for mi, rows in arc_rows.items():
        r0 = int(rows_before[mi])
        for j, row in enumerate(rows):
            b_start[r0 + j], b_end[r0 + j] = row[0], row[1]
            b_e0[r0 + j], b_de[r0 + j], b_L[r0 + j] = row[2], row[3], row[4]
            b_acc[r0 + j], b_peak[r0 + j], b_vcap[r0 + j], b_jd[r0 + j] = row[5:9]
            b_er[r0 + j] = row[11]
            if row[10] is not None:
                b_jerk[r0 + j] = [row[10][k] for k in "xyz"]

    # stops, in file order as the reference meets them: an event stops after the last block
    # before its move (or adds to the lead-in); an E-only block stops the block before it
    stop_after = np.zeros(n, bool)
    dwell = np.zeros(n)
    for ev in events:
        if ev.stop:
            k = int(rows_before[ev.move_index]) - 1
            if k >= 0:
                stop_after[k] = True
                dwell[k] = dwell[k] + ev.dwell_s
            else:
                lead += ev.dwell_s
    r = rows_before[ei_]
    stop_after[r[r > 0] - 1] = True
    stop_after[-1] = True
    stop_after |= b_eonly
    d = b_end - b_start
    nrm = np.linalg.norm(d, axis=1, keepdims=True)
    unit = np.where(nrm > 0, d / np.where(nrm > 0, nrm, 1), 0.0)
    turn = np.einsum("ij,ij->i", unit[:-1], unit[1:])
    turn = np.where(b_eonly[:-1] | b_eonly[1:], -1.0, turn)
    # classic jerk where the next block has it: the highest speed at which no axis changes
    # by more than its jerk
    dv = np.abs(unit[1:] - unit[:-1])
    with np.errstate(divide="ignore", invalid="ignore"):
        jv = np.where(dv > 1e-12, b_jerk[1:] / dv, np.inf).min(axis=1)
    jerk_v = np.where(np.isnan(b_jerk[1:, 0]), np.inf, jv)
    return Blocks(b_start, b_end, b_e0, b_de, b_L, b_acc, b_peak, b_vcap, stop_after, dwell,
                  b_jd, turn, lead, klipper, jerk_v, b_er if klipper else None,
                  fw.instantaneous_corner_velocity_mm_s)


def _marlin_fast(snaps, si, li, ei_, rl, re_, dl, L, de_total, feed, macc, mfeed, b_de, b_L,
                 b_acc, b_peak, b_vcap, b_jd):
    """Marlin's blocks of the straight moves ``li`` (rows ``rl``, deltas ``dl``, lengths
    ``L``) and the E-only moves ``ei_`` (rows ``re_``), element-wise as the reference."""
    snap_a_print = np.array([q.accel_print for q in snaps])[si]
    snap_a_travel = np.array([q.accel_travel for q in snaps])[si]
    snap_jd = np.array([q.jd for q in snaps])
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.abs(dl) / L[:, None]
        de = de_total[li] * L / L
        ue = np.abs(de) / L
        a = np.where(de_total[li] > 0, snap_a_print[li], snap_a_travel[li])
        v = feed[li]
        for k in range(3):
            big = u[:, k] > 1e-12
            a = np.where(big, np.minimum(a, macc[li, k] / u[:, k]), a)
            v = np.where(big, np.minimum(v, mfeed[li, k] / u[:, k]), v)
        big = ue > 1e-12
        a = np.where(big, np.minimum(a, macc[li, 3] / ue), a)
        v = np.where(big, np.minimum(v, mfeed[li, 3] / ue), v)
    b_de[rl] = de
    b_L[rl] = L
    b_acc[rl] = a
    b_peak[rl] = a
    b_vcap[rl] = v
    b_jd[rl] = snap_jd[si[li]]
    a = np.minimum(np.array([q.accel_retract for q in snaps])[si[ei_]], macc[ei_, 3])
    b_de[re_] = de_total[ei_]
    b_L[re_] = np.abs(de_total[ei_])
    b_acc[re_] = a
    b_peak[re_] = a
    b_vcap[re_] = np.minimum(feed[ei_], mfeed[ei_, 3])
    b_jd[re_] = snap_jd[si[ei_]]


def _klipper_fast(snaps, si, li, ei_, rl, re_, dl, L, de_total, feed, macc, mfeed, b_de, b_L,
                  b_acc, b_peak, b_vcap, b_jd, b_er):
    """:func:`_klipper_move` and :func:`_klipper_e_only` element-wise (same operations in the
    same order: bit-identical) for the straight moves ``li`` and the E-only moves ``ei_``."""
    ap = np.array([q.accel_print for q in snaps])[si]
    vel = np.array([q.velocity for q in snaps])[si]
    sf = np.array([q.speed_factor for q in snaps])[si]
    ef = np.array([q.extrude_factor for q in snaps])[si]
    pseudo = ap * (1.0 - np.array([q.min_cruise_ratio for q in snaps])[si])
    jd = np.array([q.scv ** 2 * _SCV_JD for q in snaps])[si] / ap
    with np.errstate(divide="ignore", invalid="ignore"):
        de = de_total[li] * L / L
        a = ap[li]
        v = np.minimum(feed[li] * sf[li], vel[li])
        dz = dl[:, 2]
        zr = L / np.abs(dz)
        hz = dz != 0.0
        v = np.where(hz, np.minimum(v, mfeed[li, 2] * zr), v)
        a = np.where(hz, np.minimum(a, macc[li, 2] * zr), a)
        er = de * ef[li] / L
        he = (de != 0.0) & (((dl[:, 0] == 0.0) & (dl[:, 1] == 0.0)) | (er < 0.0))
        inv = 1.0 / np.abs(er)
        v = np.where(he, np.minimum(v, mfeed[li, 3] * inv), v)
        a = np.where(he, np.minimum(a, macc[li, 3] * inv), a)
    b_de[rl] = de
    b_L[rl] = L
    b_acc[rl] = a
    b_peak[rl] = np.minimum(a, pseudo[li])
    b_vcap[rl] = v
    b_jd[rl] = jd[li]
    b_er[rl] = er
    a = macc[ei_, 3]
    b_de[re_] = de_total[ei_]
    b_L[re_] = np.abs(de_total[ei_]) * ef[ei_]
    b_acc[re_] = a
    b_peak[re_] = np.minimum(a, pseudo[ei_])
    b_vcap[re_] = np.minimum(feed[ei_] * sf[ei_], mfeed[ei_, 3])
    b_jd[re_] = jd[ei_]


def _plan(blocks: Blocks):
    n = blocks.length_mm.size
    if blocks.klipper:
        vj2 = np.zeros(n + 1)
        if n:
            vj2[1:n] = klipper_junction_v2(blocks.turn_cos, blocks.accel, blocks.jd,
                                           blocks.length_mm, blocks.vcap, blocks.stop_after,
                                           blocks.e_ratio, blocks.icv_mm_s)
        return klipper_lookahead(vj2, blocks.length_mm, blocks.accel, blocks.peak_accel,
                                 blocks.vcap, blocks.dwell_after_s, blocks.lead_s)
    # junction rule with the block's own deviation (M205 J in force), classic jerk where set
    vj = np.zeros(n + 1)
    if n:
        vj[1:n] = junction_limits(blocks.turn_cos, blocks.accel, blocks.jd[1:], None,
                                  blocks.jerk_v, blocks.vcap, blocks.stop_after,
                                  blocks.length_mm)
    vj = forward_backward(vj, blocks.length_mm, blocks.accel)
    return trapezoids(vj, blocks.length_mm, blocks.accel, blocks.vcap, blocks.dwell_after_s,
                      blocks.lead_s)


def estimate_time_s(program, profile, fast: bool = True,
                    override: AccelOverride | None = None) -> float:
    """Print time as the firmware model executes the program (no sampling), s.
    ``fast``, ``override``: see :func:`build_blocks`."""
    blocks = build_blocks(program, profile, fast, override)
    if blocks.length_mm.size == 0:
        return blocks.lead_s
    return _plan(blocks).duration_s


def execute(program, profile) -> Trajectory:
    """The commanded trajectory (X, Y, Z, E at every Ts) the firmware runs for ``program``."""
    blocks = build_blocks(program, profile)
    ts = profile.ts_s
    if blocks.length_mm.size == 0:
        k = int(math.ceil(blocks.lead_s / ts)) + 1
        return Trajectory(ts_s=ts, pos_mm=np.zeros((k, 3)), e_mm=np.zeros(k))
    tr = _plan(blocks)
    s0 = np.concatenate([[0.0], np.cumsum(blocks.length_mm)])
    s = sample(tr, s0, ts)
    i = np.clip(np.searchsorted(s0, s, side="right") - 1, 0, blocks.length_mm.size - 1)
    L = blocks.length_mm[i]
    u = np.clip(np.where(L > 0, (s - s0[i]) / np.where(L > 0, L, 1), 0.0), 0.0, 1.0)
    pos = blocks.start_mm[i] + (blocks.end_mm[i] - blocks.start_mm[i]) * u[:, None]
    e = blocks.e0_mm[i] + blocks.de_mm[i] * u
    xy = np.any(blocks.end_mm[:, :2] != blocks.start_mm[:, :2], axis=1)
    return Trajectory(ts_s=ts, pos_mm=pos, e_mm=e, in_extrusion=(xy & (blocks.de_mm > 0))[i])
