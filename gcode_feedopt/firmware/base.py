"""The small interface every firmware variant implements, and what they share.

A variant (marlin.py, klipper.py) is one printer firmware's rules, behind :class:`Firmware`:

- the settings replay: how a line of the file (M204, M201, M203, M205, SET_VELOCITY_LIMIT,
  M220, M221) changes the :class:`Limits` in force (:meth:`Firmware.apply_event`), which lines
  set an acceleration and which lower one below the plan's (``--accel plan``);
- per-move caps: the planner blocks of straight moves, arc chords and E-only moves, and the
  limits a planner must respect per move;
- the junction rule and the look-ahead that turn blocks into trapezoids;
- the text of the commands that set limits and restore them (the writer's lines).

The per-file replay of the settings is replay.py; the blocks are blocks.py.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

#: Marlin's minimum planner speed (MINIMUM_PLANNER_SPEED), mm/s: junctions never go below it
#: unless the firmware stops there.
MIN_PLANNER_SPEED_MM_S = 0.05

#: √2 − 1: Klipper's junction deviation is square_corner_velocity² (√2 − 1) / max_accel
SCV_JD = math.sqrt(2) - 1


@dataclass
class Limits:
    """The firmware's settings in force at one point of a file (the profile's, then the
    file's own lines)."""

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

    def copy(self) -> "Limits":
        """A snapshot: the dicts copied, so later lines do not change it."""
        return Limits(self.accel_print, self.accel_travel, self.accel_retract,
                      dict(self.max_accel), dict(self.max_feed), self.jd, self.scv,
                      self.min_cruise_ratio, self.velocity,
                      None if self.jerk is None else dict(self.jerk), self.speed_factor,
                      self.extrude_factor)

    def set_fields(self, fields: dict) -> None:
        """Set ``fields`` ({field: value}; ``x``, ``y``: M201 X, Y; ``jerk_x``, ``jerk_y``:
        classic jerk M205 X, Y, where it is in force)."""
        for f, v in fields.items():
            if f in ("x", "y"):
                self.max_accel[f] = v
            elif f in ("jerk_x", "jerk_y"):
                if self.jerk is not None:
                    self.jerk[f[-1]] = v
            else:
                setattr(self, f, v)

    def get_field(self, f: str):
        """The value of field ``f`` in force (as :meth:`set_fields` names them): None for
        classic jerk's fields under junction deviation, and for the junction deviation
        ``jd`` under classic jerk (Marlin's M205 J would switch the rule)."""
        if f in ("x", "y"):
            return self.max_accel[f]
        if f in ("jerk_x", "jerk_y"):
            return None if self.jerk is None else self.jerk[f[-1]]
        if f == "jd" and self.jerk is not None:
            return None
        return getattr(self, f)


def initial_limits(profile) -> Limits:
    """The limits before the first line of a file: the profile's firmware values, the
    junction settings raised to the plan's (:func:`plan_junction`)."""
    fw = profile.firmware
    pj = plan_junction(profile)
    return Limits(accel_print=fw.accel_mm_s2, accel_travel=fw.travel_accel_mm_s2,
                  accel_retract=fw.accel_mm_s2, max_accel=dict(fw.max_accel_mm_s2),
                  max_feed=dict(fw.max_feed_mm_s), jd=pj.get("jd", fw.junction_deviation_mm),
                  scv=pj.get("scv", fw.square_corner_velocity_mm_s),
                  min_cruise_ratio=fw.minimum_cruise_ratio,
                  velocity=max(fw.max_feed_mm_s["x"], fw.max_feed_mm_s["y"]))


def norm3(d) -> float:
    """Length of a 3-vector as √((dx² + dy²) + dz²), written out: the fast block builder
    computes the same expression element-wise, and ``np.linalg.norm`` does not promise that
    order (NumPy 2.4 gives a different last bit), which the bit-identity tests would see."""
    dx, dy, dz = float(d[0]), float(d[1]), float(d[2])
    return math.sqrt((dx * dx + dy * dy) + dz * dz)


def positive(p: dict, key: str) -> float | None:
    """``p[key]`` when it is a number above 0, else None."""
    v = p.get(key)
    return float(v) if isinstance(v, float) and v > 0 else None


def plan_xy_accels(profile) -> tuple:
    """(M201 X, Y) the plan runs at: the profile's firmware maxima within the machine's
    hardware limits (``limits.amax_mm_s2``, ``limits.axis_amax_mm_s2``)."""
    fw, lim = profile.firmware, profile.limits
    return tuple(min(lim.axis_amax_mm_s2[a], lim.amax_mm_s2, fw.max_accel_mm_s2[a]) for a in "xy")


def plan_junction(profile) -> dict:
    """The junction settings the plan runs at, from the machine's hardware limit J on an
    axis's instantaneous speed change (``limits.axis_jerk_mm_s``); {} when the profile states
    none (the firmware's and the file's own settings hold):

    - ``jerk_x``, ``jerk_y``: classic jerk (Marlin ``M205 X Y``), J of each axis;
    - ``jd``: the junction deviation δ whose speed step stays within J: at a turn of φ the
      junction speed is v² = a·δ·c/(1 − c), c = cos(φ/2), and the velocity changes by
      2v·sin(φ/2), so |Δv|² = 4·a·δ·c·(1 + c) < 8·a·δ: δ = J²/(8·a), J the smaller axis's,
      at the plan's highest acceleration a (a stretch slowed to r²·a steps by r·J);
    - ``scv``: Klipper's square corner velocity; its δ is scv²(√2 − 1)/a, so
      |Δv|² < 8(√2 − 1)·scv² at any acceleration: scv = J/√(8(√2 − 1)).

    Rounded down to what the written lines say (δ to 0.001 mm, scv to 0.1 mm/s), and never
    below the firmware's own."""
    lim, fw = profile.limits, profile.firmware
    if lim.axis_jerk_mm_s is None:
        return {}
    jx, jy = float(lim.axis_jerk_mm_s["x"]), float(lim.axis_jerk_mm_s["y"])
    j = min(jx, jy)
    a = min(max(fw.accel_mm_s2, fw.travel_accel_mm_s2), lim.amax_mm_s2)
    jd = math.floor(j * j / (8.0 * a) * 1000.0 + 1e-9) / 1000.0
    scv = math.floor(j / math.sqrt(8.0 * SCV_JD) * 10.0 + 1e-9) / 10.0
    return {"jerk_x": jx, "jerk_y": jy, "jd": max(jd, fw.junction_deviation_mm),
            "scv": max(scv, fw.square_corner_velocity_mm_s)}


def fmt_setting(v: float) -> str:
    """A setting as the override's lines write it: three decimals, trailing zeros dropped."""
    return f"{v:.3f}".rstrip("0").rstrip(".")


class Firmware(ABC):
    """One firmware's rules (module docstring). Stateless: one instance per flavour."""

    #: profile ``firmware.flavour``
    flavour: str = ""
    #: the file (M201) and the configuration (``firmware.configured_max_accel_mm_s2``) can set
    #: per-axis acceleration maxima
    axis_max_accel: bool = True
    #: the lines restoring a slowed stretch's settings also set the limit the clamp
    #: (firmware.AccelClamp) holds (Klipper's one ACCEL)
    restore_sets_clamp: bool = False
    #: the commands the writer's added lines may start with (gcode.verify checks them)
    limit_commands: tuple = ()
    #: the junction settings (fields of :func:`plan_junction`) the firmware follows and
    #: ``--accel plan`` raises where the file lowers them
    junction_fields: tuple = ()
    #: (field, profile ``firmware`` key) of the junction setting a file starts with
    start_junction: tuple = ()

    # -- the settings replay --------------------------------------------------------------
    @abstractmethod
    def apply_event(self, lim: Limits, ev) -> None:
        """Change ``lim`` as the line ``ev`` (gcode.reader event) does."""

    @abstractmethod
    def lowered(self, ev, plan: dict) -> dict:
        """{field: the plan's value} of the accelerations ``ev`` sets below ``plan``'s."""

    @abstractmethod
    def plan_accels(self, profile) -> tuple[float, float, tuple]:
        """(M204 P, M204 T, (M201 X, Y)) the plan runs at."""

    @abstractmethod
    def override_texts(self, fields: dict) -> list[str]:
        """The commands that set ``fields`` ({field: value}, firmware.AccelOverride)."""

    @abstractmethod
    def describe_accels(self, ov) -> str:
        """The plan's accelerations an override sets, as a person reads them."""

    # -- per-move caps --------------------------------------------------------------------
    @abstractmethod
    def e_only_accel(self, lim: Limits) -> float:
        """An E-only move's acceleration under ``lim``."""

    @abstractmethod
    def arc_segments(self, planar_mm: float, dz_mm: float, fw) -> int:
        """Number of chords the firmware cuts an arc into."""

    @abstractmethod
    def chord_row(self, lim: Limits, p0, p1, d, L: float, de: float, e0: float, feed: float,
                  base_a: float) -> tuple:
        """The block row of one straight piece (a chord of an arc, or a whole line)."""

    @abstractmethod
    def e_only_row(self, lim: Limits, de: float, feed: float) -> tuple:
        """(length, accel, peak accel, speed cap, junction deviation) of an E-only block."""

    @abstractmethod
    def straight_blocks(self, snaps, si, li, ei_, rl, re_, dl, L, de_total, feed, macc, mfeed,
                        out) -> None:
        """The blocks of straight moves ``li`` and E-only moves ``ei_``, element-wise
        (blocks.py; ``out``: the block arrays to fill)."""

    @abstractmethod
    def block_e_ratio(self, e_ratio):
        """The blocks' extruder shares (blocks.Blocks.e_ratio), or None: not used."""

    @abstractmethod
    def move_arrays(self, snaps, si, acc, m: int) -> dict:
        """jd, velocity, min_cruise_ratio of firmware.MoveLimits per move."""

    # -- the writer's settings ------------------------------------------------------------
    @abstractmethod
    def settings_jerk(self, q: Limits) -> list:
        """Classic jerk X, Y in force (NaN: none) for firmware.AccelSettings."""

    @abstractmethod
    def settings_accel(self, acc_p, acc_t, clamp):
        """(print, travel) accelerations a writer restores after a slowed stretch."""

    @abstractmethod
    def clamp_values(self, snaps, axis_amax_mm_s2: dict, events):
        """(file values per snapshot (E+1, k), cap (k,), lines that set them (E,))."""

    # -- the planner ----------------------------------------------------------------------
    @abstractmethod
    def norm_cap(self, path, acc, axis_limit: dict):
        """(N,) ``acc`` within what the firmware's own acceleration rule allows."""

    @abstractmethod
    def planner_limits(self, path, vcap, acc, axis_amax_mm_s2: dict, fw, fw_limits) -> dict:
        """The fields of plan.kinematic.PlannerLimits given the plan's own caps."""

    @abstractmethod
    def lookahead(self, junction_mm_s, length_mm, accel_mm_s2, pseudo_accel_mm_s2, vcap_mm_s,
                  dwell_after_s, lead_s):
        """The firmware's look-ahead: trapezoids (plan.trapezoid.Trapezoids)."""

    @abstractmethod
    def plan_blocks(self, blocks):
        """The trapezoids the firmware plans for its blocks (blocks.Blocks)."""

    @abstractmethod
    def e_only_caps(self, program, fw_limits) -> dict:
        """Keywords of gcode.path.build_path: what an E-only move runs at."""

    # -- the writer's lines ---------------------------------------------------------------
    @abstractmethod
    def stretch_texts(self, acc: float, r: float, settings, mi: int) -> list[str]:
        """The lines that set a slowed stretch's acceleration and junction rule."""

    @abstractmethod
    def stretch_restore_texts(self, settings, mi: int) -> list[str]:
        """The lines that give the settings in force at move ``mi`` back."""

    @abstractmethod
    def clamp_text(self, vals) -> str:
        """The line that sets the clamped acceleration limits ``vals``."""

    @abstractmethod
    def plan_limits_texts(self, fw, settings, mi: int, raised: dict) -> list[str]:
        """The lines that set the plan's limits before the first move, where the printer is
        configured lower (``raised`` records what they raised)."""

    @abstractmethod
    def configured_texts(self, fw, raised: dict) -> list[str]:
        """The lines that set the configured limits again after the last move."""


def segment_caps(path, fw_limits):
    """Per-segment accel cap, feed cap, junction deviation and jerk-rule junction speeds from
    the firmware's limits in force at each move (firmware.MoveLimits)."""
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
