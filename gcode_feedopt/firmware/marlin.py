"""Marlin 2's rules (docs/firmware.md).

Trapezoidal blocks; per-block acceleration = M204 P (print), T (travel) or R (retract),
limited per axis by M201 (a·|u_i| ≤ A_i); feed limited per axis by M203; junction speed by
junction deviation (M205 J; Marlin's formula v² = a·δ·sin(θ/2)/(1 − sin(θ/2))); G2/G3 split
into chords of ``mm_per_arc_segment`` like Marlin's plan_arc. When the file sets classic jerk
(M205 X/Y without J, as PrusaSlicer and Cura write for jerk-configured Marlin), the junction
speed is the highest at which no axis changes speed by more than its jerk.
"""

from __future__ import annotations

import math

import numpy as np

from ..gcode.motion_lines import _fmt
from ..plan.trapezoid import forward_backward, junction_limits, trapezoids
from .base import Firmware, Limits, fmt_setting, plan_xy_accels, segment_caps


class Marlin(Firmware):
    flavour = "marlin"
    axis_max_accel = True
    limit_commands = ("M201", "M204", "M205")
    junction_fields = ("jd", "jerk_x", "jerk_y")
    start_junction = ("jd", "junction_deviation_mm")

    # -- the settings replay --------------------------------------------------------------
    def apply_event(self, lim: Limits, ev) -> None:
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

    def lowered(self, ev, plan: dict) -> dict:
        p, n = ev.params, ev.name
        vals = {}
        if n == "M204":
            for key, fields in (("S", ("accel_print", "accel_travel")), ("P", ("accel_print",)),
                                ("T", ("accel_travel",))):
                if isinstance(p.get(key), float):
                    vals.update({f: p[key] for f in fields})
        elif n == "M201":
            vals = {L.lower(): p[L] for L in "XY" if isinstance(p.get(L), float)}
        elif n == "SET_VELOCITY_LIMIT" and isinstance(p.get("ACCEL"), float):
            vals = {"accel_print": p["ACCEL"], "accel_travel": p["ACCEL"]}
        elif n == "M205":
            # as apply_event reads it: J switches to junction deviation, else X/Y classic jerk
            if "J" in p:
                vals = {"jd": p["J"]} if isinstance(p["J"], float) else {}
            else:
                vals = {f"jerk_{L.lower()}": p[L] for L in "XY" if isinstance(p.get(L), float)}
        return {f: plan[f] for f, v in vals.items() if f in plan and v < plan[f]}

    def plan_accels(self, profile) -> tuple[float, float, tuple]:
        fw, lim = profile.firmware, profile.limits
        xy = plan_xy_accels(profile)
        return (min(fw.accel_mm_s2, lim.amax_mm_s2), min(fw.travel_accel_mm_s2, lim.amax_mm_s2),
                xy)

    def override_texts(self, fields: dict) -> list[str]:
        """``M204 P.. T..``, ``M201 X.. Y..``, ``M205 X.. Y..`` (classic jerk) and ``M205 J..``
        (those of them ``fields`` sets)."""
        g = fmt_setting
        out = []
        pt = [f"{L}{g(fields[f])}" for L, f in (("P", "accel_print"), ("T", "accel_travel"))
              if f in fields]
        if pt:
            out.append("M204 " + " ".join(pt))
        xy = [f"{L}{g(fields[L.lower()])}" for L in "XY" if L.lower() in fields]
        if xy:
            out.append("M201 " + " ".join(xy))
        jerk = [f"{L}{g(fields['jerk_' + L.lower()])}" for L in "XY"
                if "jerk_" + L.lower() in fields]
        if jerk:
            out.append("M205 " + " ".join(jerk))
        if "jd" in fields:
            out.append(f"M205 J{g(fields['jd'])}")
        return out

    def describe_accels(self, ov) -> str:
        out = (f"M204 P{ov.accel_print_mm_s2:g} T{ov.accel_travel_mm_s2:g}, M201 "
               f"X{ov.max_accel_xy_mm_s2[0]:g} Y{ov.max_accel_xy_mm_s2[1]:g} mm/s²")
        j = ov.junction
        parts = ["M205 " + " ".join(f"{L}{j['jerk_' + L.lower()]:g}" for L in "XY"
                                     if "jerk_" + L.lower() in j) + " mm/s (classic jerk)"
                 ] if "jerk_x" in j or "jerk_y" in j else []
        parts += [f"M205 J{j['jd']:g} mm"] if "jd" in j else []
        if parts:
            out += "; junctions " + ", ".join(parts)
        return out

    # -- per-move caps --------------------------------------------------------------------
    def e_only_accel(self, lim: Limits) -> float:
        """M204 R within M201 E."""
        return min(lim.accel_retract, lim.max_accel["e"])

    def arc_segments(self, planar_mm: float, dz_mm: float, fw) -> int:
        """ceil(planar length / mm_per_arc_segment)."""
        return max(1, int(math.ceil(planar_mm / fw.mm_per_arc_segment)))

    def chord_row(self, lim: Limits, p0, p1, d, L: float, de: float, e0: float, feed: float,
                  base_a: float) -> tuple:
        """Per-axis caps (E too: its speed is de/L times the path speed)."""
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
        return (p0, p1, e0, de, L, a, a, v, lim.jd, False, lim.jerk, 0.0)

    def e_only_row(self, lim: Limits, de: float, feed: float) -> tuple:
        a = min(lim.accel_retract, lim.max_accel["e"])
        return abs(de), a, a, min(feed, lim.max_feed["e"]), lim.jd

    def straight_blocks(self, snaps, si, li, ei_, rl, re_, dl, L, de_total, feed, macc, mfeed,
                        out) -> None:
        """Marlin's blocks of the straight moves ``li`` (rows ``rl``, deltas ``dl``, lengths
        ``L``) and the E-only moves ``ei_`` (rows ``re_``), element-wise as the reference,
        with the classic jerk in force."""
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
        out["de"][rl] = de
        out["L"][rl] = L
        out["acc"][rl] = a
        out["peak"][rl] = a
        out["vcap"][rl] = v
        out["jd"][rl] = snap_jd[si[li]]
        a = np.minimum(np.array([q.accel_retract for q in snaps])[si[ei_]], macc[ei_, 3])
        out["de"][re_] = de_total[ei_]
        out["L"][re_] = np.abs(de_total[ei_])
        out["acc"][re_] = a
        out["peak"][re_] = a
        out["vcap"][re_] = np.minimum(feed[ei_], mfeed[ei_, 3])
        out["jd"][re_] = snap_jd[si[ei_]]
        snap_jerk = np.array([[np.nan] * 3 if q.jerk is None else [q.jerk[k] for k in "xyz"]
                              for q in snaps])
        out["jerk"][rl] = snap_jerk[si[li]]
        out["jerk"][re_] = snap_jerk[si[ei_]]

    def block_e_ratio(self, e_ratio):
        """Marlin's junctions do not look at the extruder's share: None."""
        return None

    def move_arrays(self, snaps, si, acc, m: int) -> dict:
        """M205 J in force; no velocity limit of its own; no minimum_cruise_ratio."""
        return {"jd": np.array([q.jd for q in snaps])[si], "velocity": np.full(m, np.inf),
                "min_cruise_ratio": np.array([0.0 for q in snaps])[si]}

    # -- the writer's settings ------------------------------------------------------------
    def settings_jerk(self, q: Limits) -> list:
        return [np.nan] * 2 if q.jerk is None else [q.jerk["x"], q.jerk["y"]]

    def settings_accel(self, acc_p, acc_t, clamp):
        """M204 P and T as the file sets them (the clamp is on M201)."""
        return acc_p, acc_t

    def clamp_values(self, snaps, axis_amax_mm_s2: dict, events):
        """M201 X Y Z against the plan's axis limits."""
        file = np.array([[q.max_accel[k] for k in "xyz"] for q in snaps],
                        dtype=float).reshape(-1, 3)
        cap = np.array([axis_amax_mm_s2[k] for k in "xyz"], dtype=float)
        return file, cap, [ev.name == "M201" for ev in events]

    # -- the planner ----------------------------------------------------------------------
    def norm_cap(self, path, acc, axis_limit: dict):
        """Marlin's per-axis limits are all there is: ``acc`` unchanged."""
        return acc

    def planner_limits(self, path, vcap, acc, axis_amax_mm_s2: dict, fw, fw_limits) -> dict:
        """Within the file's settings (``fw_limits``), junction deviation per move, classic
        jerk where the file sets it."""
        n = path.n_segments
        jerk_v = None
        if fw_limits is not None:
            f_acc, f_vcap, jd, jerk_v = segment_caps(path, fw_limits)
            acc = np.minimum(acc, f_acc)
            vcap = np.minimum(vcap, f_vcap)
        else:
            jd = np.full(n, fw.junction_deviation_mm)
        vj = np.zeros(n + 1)
        if n:
            vj[1:n] = junction_limits(path.junction_cos(), acc, jd[1:], None, jerk_v, vcap,
                                      path.stop_after, path.length_mm)
        jerk_j = None
        if jerk_v is not None and n:
            jerk_j = np.zeros(n + 1, bool)
            jerk_j[1:n] = np.isfinite(jerk_v)
        return {"vcap_mm_s": vcap, "accel_mm_s2": acc, "junction_mm_s": vj,
                "jerk_junction": jerk_j}

    def lookahead(self, junction_mm_s, length_mm, accel_mm_s2, pseudo_accel_mm_s2, vcap_mm_s,
                  dwell_after_s, lead_s):
        """Forward-backward pass over the junction limits, then the trapezoids."""
        vj = forward_backward(junction_mm_s, length_mm, accel_mm_s2)
        return trapezoids(vj, length_mm, accel_mm_s2, vcap_mm_s, dwell_after_s, lead_s)

    def plan_blocks(self, blocks):
        """Junction rule with the block's own deviation (M205 J in force), classic jerk where
        set."""
        n = blocks.length_mm.size
        vj = np.zeros(n + 1)
        if n:
            vj[1:n] = junction_limits(blocks.turn_cos, blocks.accel, blocks.jd[1:], None,
                                      blocks.jerk_v, blocks.vcap, blocks.stop_after,
                                      blocks.length_mm)
        return self.lookahead(vj, blocks.length_mm, blocks.accel, None, blocks.vcap,
                              blocks.dwell_after_s, blocks.lead_s)

    def e_only_caps(self, program, fw_limits) -> dict:
        """M203 E and M204 R within M201 E."""
        return {"e_feed_cap_mm_s": fw_limits.e_feed_mm_s, "e_accel_mm_s2": fw_limits.e_accel_mm_s2}

    # -- the writer's lines ---------------------------------------------------------------
    def stretch_texts(self, acc: float, r: float, settings, mi: int) -> list[str]:
        """``M204 P T``, and ``M205 X Y`` scaled by r when the file uses classic jerk."""
        a = _fmt(acc, 3)
        out = [f"M204 P{a} T{a}"]
        j = _jerk(settings, mi)
        if j is not None:
            out.append(f"M205 X{_fmt(j[0] * r, 3)} Y{_fmt(j[1] * r, 3)}")
        return out

    def stretch_restore_texts(self, settings, mi: int) -> list[str]:
        out = [f"M204 P{_fmt(float(settings.accel_print_mm_s2[mi]), 3)} "
               f"T{_fmt(float(settings.accel_travel_mm_s2[mi]), 3)}"]
        j = _jerk(settings, mi)
        if j is not None:
            out.append(f"M205 X{_fmt(j[0], 3)} Y{_fmt(j[1], 3)}")
        return out

    def clamp_text(self, vals) -> str:
        return "M201 " + " ".join(f"{a}{_fmt(v, 3)}" for a, v in zip("XYZ", vals))

    def plan_limits_texts(self, fw, settings, mi: int, raised: dict) -> list[str]:
        """``M201 X Y`` then ``M204 P R T``, those the configuration holds lower, and ``M205 J``
        where the plan's junction deviation is above the firmware's (firmware.plan_junction)."""
        st, out = settings, []
        conf_a, conf_m = fw.configured_accel_mm_s2, fw.configured_max_accel_mm_s2
        p, t = float(st.accel_print_mm_s2[mi]), float(st.accel_travel_mm_s2[mi])
        if conf_m is not None and st.max_accel_xy_mm_s2 is not None:
            mx, my = (float(v) for v in st.max_accel_xy_mm_s2[mi])
            if mx > conf_m["x"] or my > conf_m["y"]:
                out.append(f"M201 X{_fmt(mx, 3)} Y{_fmt(my, 3)}")
                raised["max"] = True
        r = p if st.accel_retract_mm_s2 is None else float(st.accel_retract_mm_s2[mi])
        if conf_a is not None and max(p, t, r) > conf_a:
            out.append(f"M204 P{_fmt(p, 3)} R{_fmt(r, 3)} T{_fmt(t, 3)}")
            raised["accel"] = True
        if (st.jd_mm is not None and np.isnan(st.jerk_xy_mm_s[mi][0])
                and float(st.jd_mm[mi]) > fw.junction_deviation_mm):
            out.append(f"M205 J{fmt_setting(float(st.jd_mm[mi]))}")
            raised["junction"] = True
        return out

    def configured_texts(self, fw, raised: dict) -> list[str]:
        out = []
        if raised["max"]:
            c = fw.configured_max_accel_mm_s2
            out.append(f"M201 X{_fmt(c['x'], 3)} Y{_fmt(c['y'], 3)}")
        if raised["accel"]:
            a = _fmt(fw.configured_accel_mm_s2, 3)
            out.append(f"M204 P{a} R{a} T{a}")
        if raised.get("junction"):
            out.append(f"M205 J{fmt_setting(fw.junction_deviation_mm)}")
        return out


def _jerk(settings, mi: int):
    """Classic jerk X, Y in force at move ``mi``, or None (junction deviation)."""
    j = settings.jerk_xy_mm_s[mi]
    return None if np.isnan(j[0]) else j
