"""Klipper's rules: klippy's (commit 84104bb; docs/firmware.md).

One accel (M204 S, or the smaller of M204 P and T; P or T alone, M204 R, M201, M203 and M205
change nothing), SET_VELOCITY_LIMIT (VELOCITY, ACCEL, SQUARE_CORNER_VELOCITY,
MINIMUM_CRUISE_RATIO), M220 / M221; Z and extrude-only limits scaled by the move; junctions at
each neighbour's own δ·a (δ = scv²(√2 − 1)/accel) and ½·L·a·tan(θ/2), and the extruder's
instantaneous_corner_velocity; minimum_cruise_ratio's pseudo-accel look-ahead gives a run of
short moves one reduced peak (:func:`klipper_lookahead`). Real Klipper times the same
files to within 1 µs (tests/vm/test_klipper_referee.py).
"""

from __future__ import annotations

import math

import numpy as np

from ..gcode.motion_lines import _fmt
from ..gcode.path import SEG_LINE
from ..plan.trapezoid import Trapezoids, trapezoids_from_speeds
from .base import (SCV_JD, Firmware, Limits, fmt_setting, plan_xy_accels, positive,
                   segment_caps)


def accel_set(ev) -> float | None:
    """The accel a line sets in Klipper (``M204 S``, the smaller of ``M204 P T``,
    ``SET_VELOCITY_LIMIT ACCEL``), or None: it sets none (or Klipper refuses it)."""
    p = ev.params
    if ev.name == "M204":
        a = positive(p, "S")
        if a is None:
            pa, ta = positive(p, "P"), positive(p, "T")
            a = None if pa is None or ta is None else min(pa, ta)
        return a
    if ev.name == "SET_VELOCITY_LIMIT":
        return positive(p, "ACCEL")
    return None


def klipper_junction_v2(turn_cos: np.ndarray, accel_mm_s2: np.ndarray,
                        deviation_mm: np.ndarray, length_mm: np.ndarray, vcap_mm_s: np.ndarray,
                        stop_after: np.ndarray, e_ratio: np.ndarray | None = None,
                        icv_mm_s: float = 1.0) -> np.ndarray:
    """(N-1,) squared speed limit at each inner junction under Klipper's rules, (mm/s)².

    Klipper (toolhead.Move.calc_junction) takes the smallest of: both neighbours' speed caps;
    the extruder's ``(icv / |Δ(dE/L)|)²`` where the share of E changes (``e_ratio``,
    instantaneous_corner_velocity ``icv_mm_s``); and, unless the path goes straight on, the
    junction deviation v² = R·δ·a and the centripetal rule v² = ½·L·a·tan(θ/2) of each
    neighbour with its own δ, a and L, R = sin(θ/2)/(1 − sin(θ/2)) (θ between the reversed
    incoming and the outgoing direction). Unlike plan.trapezoid.junction_speeds no turn
    counts as straight or as a reversal by a threshold: the formulas decide. Exact stops give 0.
    """
    a = accel_mm_s2
    cap2 = vcap_mm_s * vcap_mm_s
    v2 = np.minimum(cap2[:-1], cap2[1:])
    if e_ratio is not None:
        dr = np.abs(e_ratio[1:] - e_ratio[:-1])
        with np.errstate(divide="ignore"):
            v2 = np.where(dr != 0.0, np.minimum(v2, np.square(icv_mm_s / dr)), v2)
    jct = -np.asarray(turn_cos, float)
    sin_d2 = np.sqrt(np.maximum(0.5 * (1.0 - jct), 0.0))
    cos_d2 = np.sqrt(np.maximum(0.5 * (1.0 + jct), 0.0))
    oms = 1.0 - sin_d2
    turn = (oms > 0.0) & (cos_d2 > 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        r_jd = sin_d2 / oms
        qtan = 0.25 * sin_d2 / cos_d2
        lim = np.minimum(np.minimum(r_jd * deviation_mm[1:] * a[1:],
                                    r_jd * deviation_mm[:-1] * a[:-1]),
                         np.minimum(2.0 * length_mm[1:] * a[1:] * qtan,
                                    2.0 * length_mm[:-1] * a[:-1] * qtan))
    v2 = np.where(turn, np.minimum(v2, lim), v2)
    return np.where(stop_after[:-1], 0.0, v2)


def klipper_lookahead(junction_v2: np.ndarray, length_mm: np.ndarray, accel_mm_s2: np.ndarray,
                      pseudo_accel_mm_s2: np.ndarray, vcap_mm_s: np.ndarray,
                      dwell_s: np.ndarray, lead_s: float = 0.0) -> Trapezoids:
    """Klipper's look-ahead (toolhead.LookAheadQueue.flush) over a whole chain, as trapezoids.

    ``junction_v2`` (N+1,) the squared junction limits (:func:`klipper_junction_v2`; 0 at both
    ends and at stops). Two speed profiles are planned: the real one at each block's accel and
    minimum_cruise_ratio's at its pseudo-accel (never above the accel). Forward, each start
    is what the previous block can reach; backward, what the next one can brake from. A block
    that accelerates in the pseudo profile cruises at most at the pseudo profile's peak of the
    stretch of accelerating blocks it belongs to (the peak of the block where that profile
    turns from accelerating to braking) — so a run of short moves shares one reduced peak
    instead of each reaching its own; a block that only brakes in the pseudo profile cruises
    no faster than the block before it. Each block then runs start → cruise → end at its
    accel, its ends cut to its cruise. A stop resets both profiles, as a flush of Klipper's
    queue does, so one pass over the whole chain is the same as Klipper's flushes.
    """
    n = int(length_mm.size)
    L = length_mm
    delta = (2.0 * accel_mm_s2 * L).tolist()
    mdelta = (2.0 * np.minimum(pseudo_accel_mm_s2, accel_mm_s2) * L).tolist()
    cap2 = np.square(vcap_mm_s).tolist()
    lim = junction_v2.tolist()
    # forward: the highest start of each block, real and pseudo
    ms = [0.0] * n
    mm = [0.0] * n
    for i in range(1, n):
        v = lim[i]
        r = ms[i - 1] + delta[i - 1]
        s = v if v < r else r
        ms[i] = s
        r = mm[i - 1] + mdelta[i - 1]
        mm[i] = s if s < r else r
    # backward: starts and cruise speeds
    start = [0.0] * n
    nxt = [0.0] * n
    cruise = [-1.0] * n
    next_s = next_m = peak = 0.0
    pending = 0
    for i in range(n - 1, -1, -1):
        reach = next_s + delta[i]
        s = ms[i] if ms[i] < reach else reach
        pending += 1
        reach_m = next_m + mdelta[i]
        m = mm[i] if mm[i] < reach_m else reach_m
        if m < reach_m:
            if m + mdelta[i] > next_m or pending > 1:
                peak = (m + reach_m) * 0.5
            c = (s + reach) * 0.5
            if cap2[i] < c:
                c = cap2[i]
            if peak < c:
                c = peak
            cruise[i] = c
            pending = 0
        start[i] = s
        nxt[i] = next_s
        next_s = s
        next_m = m
    # forward: a block that only brakes cruises no faster than the one before
    v0 = [0.0] * n
    v1 = [0.0] * n
    prev = 0.0
    for i in range(n):
        c = cruise[i]
        if c < 0.0:
            c = prev if prev < start[i] else start[i]
            cruise[i] = c
        v0[i] = start[i] if start[i] < c else c
        v1[i] = nxt[i] if nxt[i] < c else c
        prev = c
    return trapezoids_from_speeds(np.sqrt(np.asarray(v0)), np.sqrt(np.asarray(cruise)),
                                  np.sqrt(np.asarray(v1)), L, accel_mm_s2, dwell_s, lead_s)


def move_caps(lim: Limits, d, L: float, de: float, feed: float):
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
    jd = lim.scv ** 2 * SCV_JD / lim.accel_print
    return a, peak_a, v, jd, er


class Klipper(Firmware):
    flavour = "klipper"
    #: M201 is not a Klipper command; max_accel is the one accel
    axis_max_accel = False
    restore_sets_clamp = True
    limit_commands = ("SET_VELOCITY_LIMIT",)
    junction_fields = ("scv",)
    start_junction = ("scv", "square_corner_velocity_mm_s")

    # -- the settings replay --------------------------------------------------------------
    def apply_event(self, lim: Limits, ev) -> None:
        """Klipper's commands that change the motion (klippy toolhead.py and gcode_move.py):
        ``M204 S`` sets the one acceleration, or ``M204 P.. T..`` the smaller of the two (P or
        T alone is refused: nothing changes); SET_VELOCITY_LIMIT VELOCITY / ACCEL /
        SQUARE_CORNER_VELOCITY / MINIMUM_CRUISE_RATIO; M220 / M221 the speed and extrusion
        factors. M201, M203, M205 and M204 R are not Klipper commands: ignored. Both accels
        of ``Limits`` hold the one accel."""
        p = ev.params
        n = ev.name
        a = accel_set(ev)
        if a is not None:
            lim.accel_print = lim.accel_travel = a
        if n == "SET_VELOCITY_LIMIT":
            if positive(p, "VELOCITY") is not None:
                lim.velocity = p["VELOCITY"]
            v = p.get("SQUARE_CORNER_VELOCITY")
            if isinstance(v, float) and v >= 0:
                lim.scv = v
            v = p.get("MINIMUM_CRUISE_RATIO")
            if isinstance(v, float) and 0 <= v < 1:
                lim.min_cruise_ratio = v
        elif n in ("M220", "M221") and ("S" not in p or positive(p, "S") is not None):
            f = p.get("S", 100.0) / 100.0
            if n == "M220":
                lim.speed_factor = f
            else:
                lim.extrude_factor = f

    def lowered(self, ev, plan: dict) -> dict:
        a = accel_set(ev)
        vals = {} if a is None else {"accel_print": a, "accel_travel": a}
        if ev.name == "SET_VELOCITY_LIMIT":
            v = ev.params.get("SQUARE_CORNER_VELOCITY")
            if isinstance(v, float) and v >= 0:
                vals["scv"] = v
        return {f: plan[f] for f, v in vals.items() if f in plan and v < plan[f]}

    def plan_accels(self, profile) -> tuple[float, float, tuple]:
        """The one accel within both axes' limits."""
        xy = plan_xy_accels(profile)
        a = min(profile.firmware.accel_mm_s2, *xy)
        return a, a, xy

    def override_texts(self, fields: dict) -> list[str]:
        """``SET_VELOCITY_LIMIT ACCEL=.. SQUARE_CORNER_VELOCITY=..`` (those ``fields`` sets)."""
        a = fields.get("accel_print", fields.get("accel_travel"))
        parts = ([f"ACCEL={fmt_setting(a)}"] if a is not None else []) + (
            [f"SQUARE_CORNER_VELOCITY={fmt_setting(fields['scv'])}"] if "scv" in fields else [])
        return ["SET_VELOCITY_LIMIT " + " ".join(parts)] if parts else []

    def describe_accels(self, ov) -> str:
        out = f"ACCEL {ov.accel_print_mm_s2:g} mm/s²"
        if "scv" in ov.junction:
            out += f"; junctions SQUARE_CORNER_VELOCITY {ov.junction['scv']:g} mm/s"
        return out

    # -- per-move caps --------------------------------------------------------------------
    def e_only_accel(self, lim: Limits) -> float:
        """max_extrude_only_accel."""
        return lim.max_accel["e"]

    def arc_segments(self, planar_mm: float, dz_mm: float, fw) -> int:
        """[gcode_arcs] floor(helix length / resolution) (at least one)."""
        return max(1, int(math.floor(math.hypot(planar_mm, dz_mm) / fw.mm_per_arc_segment)))

    def chord_row(self, lim: Limits, p0, p1, d, L: float, de: float, e0: float, feed: float,
                  base_a: float) -> tuple:
        a, peak_a, v, jd, er = move_caps(lim, d, L, de, feed)
        return (p0, p1, e0, de, L, a, peak_a, v, jd, False, None, er)

    def e_only_row(self, lim: Limits, de: float, feed: float) -> tuple:
        """The extrude-only limits; F × M220 not capped by max_velocity."""
        a = lim.max_accel["e"]
        return (abs(de) * lim.extrude_factor, a,
                min(a, lim.accel_print * (1.0 - lim.min_cruise_ratio)),
                min(feed * lim.speed_factor, lim.max_feed["e"]),
                lim.scv ** 2 * SCV_JD / lim.accel_print)

    def straight_blocks(self, snaps, si, li, ei_, rl, re_, dl, L, de_total, feed, macc, mfeed,
                        out) -> None:
        """:func:`move_caps` and :meth:`e_only_row` element-wise (same operations in the same
        order: bit-identical) for the straight moves ``li`` and the E-only moves ``ei_``."""
        ap = np.array([q.accel_print for q in snaps])[si]
        vel = np.array([q.velocity for q in snaps])[si]
        sf = np.array([q.speed_factor for q in snaps])[si]
        ef = np.array([q.extrude_factor for q in snaps])[si]
        pseudo = ap * (1.0 - np.array([q.min_cruise_ratio for q in snaps])[si])
        jd = np.array([q.scv ** 2 * SCV_JD for q in snaps])[si] / ap
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
        out["de"][rl] = de
        out["L"][rl] = L
        out["acc"][rl] = a
        out["peak"][rl] = np.minimum(a, pseudo[li])
        out["vcap"][rl] = v
        out["jd"][rl] = jd[li]
        out["er"][rl] = er
        a = macc[ei_, 3]
        out["de"][re_] = de_total[ei_]
        out["L"][re_] = np.abs(de_total[ei_]) * ef[ei_]
        out["acc"][re_] = a
        out["peak"][re_] = np.minimum(a, pseudo[ei_])
        out["vcap"][re_] = np.minimum(feed[ei_] * sf[ei_], mfeed[ei_, 3])
        out["jd"][re_] = jd[ei_]

    def block_e_ratio(self, e_ratio):
        """Held to instantaneous_corner_velocity at each junction."""
        return e_ratio

    def move_arrays(self, snaps, si, acc, m: int) -> dict:
        """Junction deviation from square_corner_velocity and the one accel; max_velocity;
        minimum_cruise_ratio."""
        return {"jd": np.array([q.scv ** 2 * (math.sqrt(2) - 1) for q in snaps])[si] / acc,
                "velocity": np.array([q.velocity for q in snaps])[si],
                "min_cruise_ratio": np.array([q.min_cruise_ratio for q in snaps])[si]}

    # -- the writer's settings ------------------------------------------------------------
    def settings_jerk(self, q: Limits) -> list:
        """No classic jerk in Klipper."""
        return [np.nan] * 2

    def settings_accel(self, acc_p, acc_t, clamp):
        """The one accel as clamped to the plan's limits (what a writer restores after a
        slowed stretch is then the clamped value)."""
        if clamp is not None:
            acc_p = np.minimum(acc_p, clamp.want_mm_s2[:, 0])
            acc_t = np.minimum(acc_t, clamp.want_mm_s2[:, 0])
        return acc_p, acc_t

    def clamp_values(self, snaps, axis_amax_mm_s2: dict, events):
        """The one ACCEL against the smaller X/Y limit."""
        file = np.array([[q.accel_print] for q in snaps], dtype=float).reshape(-1, 1)
        cap = np.array([min(axis_amax_mm_s2["x"], axis_amax_mm_s2["y"])])
        return file, cap, [accel_set(ev) is not None for ev in events]

    # -- the planner ----------------------------------------------------------------------
    def norm_cap(self, path, acc, axis_limit: dict):
        """Klipper has one acceleration, the vector's norm: where the writer clamps it to the
        plan's limits (firmware.accel_clamp) a diagonal XY move gets no more than an axis."""
        t_beg, _ = path.end_tangents()
        xy = np.hypot(t_beg[:, 0], t_beg[:, 1]) > 1e-12
        acc = acc.copy()
        acc[xy] = np.minimum(acc[xy], min(axis_limit["x"], axis_limit["y"]))
        return acc

    def planner_limits(self, path, vcap, acc, axis_amax_mm_s2: dict, fw, fw_limits) -> dict:
        """Klipper's one accel is what the writer leaves in force: the file's (M204 S, M204
        P T, SET_VELOCITY_LIMIT ACCEL), clamped to the plan's X/Y limit
        (firmware.accel_clamp); its junction deviation comes from that accel and
        square_corner_velocity, and each side of a junction gets δ·a with its own segment's
        accel (so moves slowed by Z get slower corners). A segment that retracts, or extrudes
        without moving X/Y, stays within the extrude-only limits scaled by L/|dE|; where the
        extruder's share dE/L changes, the junction stays within
        instantaneous_corner_velocity / |Δ(dE/L)|; minimum_cruise_ratio gives the plan its
        pseudo-accel (:func:`klipper_lookahead`)."""
        n = path.n_segments
        L = path.length_mm
        a_xy = min(axis_amax_mm_s2["x"], axis_amax_mm_s2["y"])
        if fw_limits is not None:
            mi = path.move_index
            f_acc, f_vcap, jd_file, _ = segment_caps(path, fw_limits)
            acc = np.minimum(acc, f_acc)
            vcap = np.minimum(vcap, f_vcap)
            file_a = fw_limits.accel_mm_s2[mi]
            toolhead = np.minimum(file_a, a_xy)
            jd = jd_file * file_a / toolhead
            mcr = fw_limits.min_cruise_ratio[mi]
            ef = fw_limits.extrude_factor[mi]
            e_feed, e_acc = fw_limits.e_feed_mm_s[mi], fw_limits.e_accel_mm_s2[mi]
        else:
            toolhead = np.full(n, min(fw.accel_mm_s2, a_xy))
            scv = fw.square_corner_velocity_mm_s
            jd = scv * scv * (math.sqrt(2.0) - 1.0) / toolhead
            mcr = np.full(n, fw.minimum_cruise_ratio)
            ef = np.ones(n)
            e_feed = np.full(n, fw.max_feed_mm_s["e"])
            e_acc = np.full(n, fw.max_accel_mm_s2["e"])
        with np.errstate(divide="ignore", invalid="ignore"):
            e_ratio = np.where(L > 0, path.de_mm * ef / np.where(L > 0, L, 1.0), 0.0)
            no_xy = ((path.end_mm[:, 0] == path.start_mm[:, 0])
                     & (path.end_mm[:, 1] == path.start_mm[:, 1]) & (path.kind == SEG_LINE))
            e_lim = (e_ratio != 0.0) & (no_xy | (e_ratio < 0.0))
            inv = 1.0 / np.abs(e_ratio)
            vcap = np.where(e_lim, np.minimum(vcap, e_feed * inv), vcap)
            acc = np.where(e_lim, np.minimum(acc, e_acc * inv), acc)
        vj = np.zeros(n + 1)
        if n:
            vj[1:n] = np.sqrt(klipper_junction_v2(path.junction_cos(), acc, jd, L, vcap,
                                                  path.stop_after, e_ratio,
                                                  fw.instantaneous_corner_velocity_mm_s))
        pseudo = np.minimum(acc, toolhead * (1.0 - mcr))
        return {"vcap_mm_s": vcap, "accel_mm_s2": acc, "junction_mm_s": vj,
                "pseudo_accel_mm_s2": pseudo}

    def lookahead(self, junction_mm_s, length_mm, accel_mm_s2, pseudo_accel_mm_s2, vcap_mm_s,
                  dwell_after_s, lead_s):
        """minimum_cruise_ratio's pseudo-accel look-ahead (:func:`klipper_lookahead`)."""
        return klipper_lookahead(np.square(junction_mm_s), length_mm, accel_mm_s2,
                                 pseudo_accel_mm_s2, vcap_mm_s, dwell_after_s, lead_s)

    def plan_blocks(self, blocks):
        vj2 = np.zeros(blocks.length_mm.size + 1)
        n = blocks.length_mm.size
        if n:
            vj2[1:n] = klipper_junction_v2(blocks.turn_cos, blocks.accel, blocks.jd,
                                           blocks.length_mm, blocks.vcap, blocks.stop_after,
                                           blocks.e_ratio, blocks.icv_mm_s)
        return klipper_lookahead(vj2, blocks.length_mm, blocks.accel, blocks.peak_accel,
                                 blocks.vcap, blocks.dwell_after_s, blocks.lead_s)

    def e_only_caps(self, program, fw_limits) -> dict:
        """E scaled by M221; minimum_cruise_ratio's pseudo-accel caps the peak of an E-only
        move at √(a_pseudo·|dE|) (its look-ahead on a lone block)."""
        de = np.abs(np.array([mv.de_mm for mv in program.moves], dtype=float))
        d = de * fw_limits.extrude_factor
        pseudo = np.minimum(fw_limits.e_accel_mm_s2,
                            fw_limits.accel_mm_s2 * (1.0 - fw_limits.min_cruise_ratio))
        cap = np.minimum(fw_limits.e_feed_mm_s, np.sqrt(pseudo * d))
        return {"e_feed_cap_mm_s": cap, "e_accel_mm_s2": fw_limits.e_accel_mm_s2,
                "e_scale": fw_limits.extrude_factor}

    # -- the writer's lines ---------------------------------------------------------------
    def stretch_texts(self, acc: float, r: float, settings, mi: int) -> list[str]:
        """``SET_VELOCITY_LIMIT ACCEL SQUARE_CORNER_VELOCITY`` (the latter scaled by r)."""
        return [f"SET_VELOCITY_LIMIT ACCEL={_fmt(acc, 3)} SQUARE_CORNER_VELOCITY="
                f"{_fmt(float(settings.scv_mm_s[mi]) * r, 3)}"]

    def stretch_restore_texts(self, settings, mi: int) -> list[str]:
        return [f"SET_VELOCITY_LIMIT ACCEL={_fmt(float(settings.accel_print_mm_s2[mi]), 3)} "
                f"SQUARE_CORNER_VELOCITY={_fmt(float(settings.scv_mm_s[mi]), 3)}"]

    def clamp_text(self, vals) -> str:
        return f"SET_VELOCITY_LIMIT ACCEL={_fmt(vals[0], 3)}"

    def plan_limits_texts(self, fw, settings, mi: int, raised: dict) -> list[str]:
        """``SET_VELOCITY_LIMIT ACCEL`` where the configured accel is lower, and
        ``SQUARE_CORNER_VELOCITY`` where the plan's is above the firmware's
        (firmware.plan_junction)."""
        p = float(settings.accel_print_mm_s2[mi])
        scv = float(settings.scv_mm_s[mi])
        conf_a = fw.configured_accel_mm_s2
        parts = []
        if conf_a is not None and p > conf_a:
            raised["accel"] = True
            parts.append(f"ACCEL={_fmt(p, 3)}")
        if scv > fw.square_corner_velocity_mm_s:
            raised["junction"] = True
            parts.append(f"SQUARE_CORNER_VELOCITY={fmt_setting(scv)}")
        return ["SET_VELOCITY_LIMIT " + " ".join(parts)] if parts else []

    def configured_texts(self, fw, raised: dict) -> list[str]:
        parts = ([f"ACCEL={_fmt(fw.configured_accel_mm_s2, 3)}"] if raised["accel"] else []) + (
            [f"SQUARE_CORNER_VELOCITY={fmt_setting(fw.square_corner_velocity_mm_s)}"]
            if raised.get("junction") else [])
        return ["SET_VELOCITY_LIMIT " + " ".join(parts)] if parts else []
