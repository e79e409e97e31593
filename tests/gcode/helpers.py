"""Shared helpers for the G-code tests."""

from __future__ import annotations

from gcode_feedopt.gcode.path import build_path
from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.gcode.verify import verify
from gcode_feedopt.gcode.writer import write
from gcode_feedopt.plan.kinematic import plan_kinematic, segment_accel
from gcode_feedopt.profile import load_profile

PROFILE = load_profile("ender3pro")


def run(data: bytes, profile=PROFILE, mode="refeed"):
    fw = profile.firmware
    prog = read_program(data, "t.gcode", flavour=fw.flavour, g91_relative_e=fw.g91_relative_e)
    path = build_path(prog)
    sched = plan_kinematic(path, profile)
    res = write(prog, path, sched, profile, mode=mode, accel_mm_s2=segment_accel(path, profile))
    verify(prog, res, flavour=fw.flavour, g91_relative_e=fw.g91_relative_e)
    out = read_program(res.data, "o.gcode", flavour=fw.flavour, g91_relative_e=fw.g91_relative_e)
    return prog, path, sched, res, out


def positions_after_moves(prog):
    """Machine position and E after every move, in order."""
    return [(m.end_mm, m.e_end_mm) for m in prog.moves]
