"""The firmware model move by move: the references the fast paths (gcode_feedopt.firmware:
the settings replayed once, blocks as arrays) are tested against, bit for bit. Used by tests
only; slow (every move and every chord one by one)."""

from __future__ import annotations

import math

import numpy as np

from gcode_feedopt.firmware import Blocks, MoveLimits, firmware_for
from gcode_feedopt.firmware.base import initial_limits, norm3
from gcode_feedopt.firmware.blocks import arc_points


def move_limits(program, profile, override=None) -> MoveLimits:
    """firmware.move_limits, the events applied move by move."""
    fwv = firmware_for(profile)
    klipper = fwv.flavour == "klipper"
    lim = initial_limits(profile)
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
            fwv.apply_event(lim, events[ei])
            if ei in over:
                lim.set_fields(over[ei])
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
        e_acc[mi] = fwv.e_only_accel(lim)
        e_feed[mi] = lim.max_feed["e"]
        mcr[mi] = lim.min_cruise_ratio if klipper else 0.0
        ef[mi] = lim.extrude_factor
    return MoveLimits(acc, macc, mfeed, jd, jerk, vel, e_acc, e_feed, mcr, ef)


def build_blocks(program, profile, override=None) -> Blocks:
    """firmware.build_blocks move by move."""
    fw = profile.firmware
    fwv = firmware_for(profile)
    lim = initial_limits(profile)
    events = program.events
    over = override.events if override is not None else {}
    ei = 0
    rows = []  # (start, end, e0, de, L, accel, peak_accel, vcap, jd, eonly, jerk, e ratio)
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
            fwv.apply_event(lim, ev)
            if ei in over:
                lim.set_fields(over[ei])
            if ev.stop:
                stop(ev.dwell_s)
            ei += 1
        feed = mv.feed_mm_s
        if mv.arc is not None:
            planar = abs(mv.arc.sweep_rad) * mv.arc.radius_mm
            pts = arc_points(mv, fwv.arc_segments(planar, mv.end_mm[2] - mv.start_mm[2], fw))
        else:
            pts = [np.asarray(mv.start_mm, float), np.asarray(mv.end_mm, float)]
        total = sum(norm3(pts[j + 1] - pts[j]) for j in range(len(pts) - 1))
        de_total = mv.de_mm
        if total <= 1e-9:
            if abs(de_total) <= 1e-12:
                continue
            # E-only block: a stop on both sides
            L, a, peak_a, v, jd = fwv.e_only_row(lim, de_total, feed)
            if rows:
                stop(0.0)
            rows.append((pts[0], pts[0], mv.e_start_mm, de_total, L, a, peak_a, v, jd, True,
                         lim.jerk, 0.0))
            stop(0.0)
            continue
        e0 = mv.e_start_mm
        base_a = lim.accel_print if de_total > 0 else lim.accel_travel
        for j in range(len(pts) - 1):
            d = pts[j + 1] - pts[j]
            L = norm3(d)
            if L <= 1e-12:
                continue
            de = de_total * L / total
            rows.append(fwv.chord_row(lim, pts[j], pts[j + 1], d, L, de, e0, feed, base_a))
            e0 += de
    while ei < len(events):
        if events[ei].stop:
            stop(events[ei].dwell_s)
        ei += 1
    return _blocks(rows, stop_idx, lead, fwv, fw)


def _blocks(rows, stop_idx, lead, fwv, fw) -> Blocks:
    klipper = fwv.flavour == "klipper"
    n = len(rows)
    if n == 0:
        z = np.zeros(0)
        return Blocks(np.zeros((0, 3)), np.zeros((0, 3)), z, z, z, z, z, z, np.zeros(0, bool), z,
                      z, z, lead, fwv)
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
    return Blocks(start, end, e0, de, L, acc, peak, vcap, stop_after, dwell, jd, turn, lead, fwv,
                  jerk_v, e_ratio if klipper else None, fw.instantaneous_corner_velocity_mm_s)


def estimate_time_s(program, profile, override=None) -> float:
    """vm.firmware.estimate_time_s on the reference's blocks."""
    blocks = build_blocks(program, profile, override)
    if blocks.length_mm.size == 0:
        return blocks.lead_s
    return blocks.plan().duration_s
