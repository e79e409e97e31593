"""Safety checks on the output before it replaces anything, and the atomic write.

The output is re-read with the same reader (an independent parse of what we wrote) and
checked against the input:

1. every line we did not re-time or update is byte-identical and in the same order;
2. the extrusion of every original move equals the sum over its sub-moves within 1e-6 mm;
3. every original move still ends at its original coordinates (1e-9 mm) — so the part is the
   same part; no line we added other than the re-timed pieces moves the machine, and the
   acceleration lines (around slowed stretches, the plan's limits where the file's are
   higher or the printer is configured lower, the plan's accelerations after the file's lines
   that lower them under ``--accel plan``) are M201 / M204 / M205 / SET_VELOCITY_LIMIT only;
4. the output has exactly one more ident line than the input.

Any failure raises VerifyError and nothing is written.
"""

from __future__ import annotations

import pathlib

from ..errors import VerifyError
from ..firmware import LIMIT_COMMANDS
from ..outputs import write_bytes
from .reader import Program, read_program, split_lines
from .writer import T_ACCEL, T_IDENT, T_META, T_NEW, T_ORIG, WriteResult

E_TOL_MM = 1e-6
#: the commands the firmware variants write to set limits, with the space after them
_ACCEL_LINE = tuple(c.encode() + b" " for c in LIMIT_COMMANDS)
XYZ_TOL_MM = 1e-9


def verify(program: Program, result: WriteResult, *, flavour: str, g91_relative_e: bool,
           name: str = "<output>") -> Program:
    """Raise VerifyError if the output breaks an invariant (see module docstring); return the
    output as parsed (the firmware model times it)."""
    out_lines = split_lines(result.data)
    if len(out_lines) != len(result.tags):
        raise VerifyError(f"{name}: internal error: {len(out_lines)} lines written but "
                          f"{len(result.tags)} tagged; nothing was written")
    # 1. untouched lines, in order
    expect = 0
    in_lines = program.lines
    retimed_lines = {program.moves[i].line_no for tag, i in result.tags if tag == T_NEW}
    for k, (tag, i) in enumerate(result.tags):
        if tag in (T_ORIG, T_META):
            while expect < len(in_lines) and (expect in retimed_lines):
                expect += 1
            if i != expect:
                raise VerifyError(f"{name}:{k + 1}: input line {expect + 1} is missing or out of "
                                  "order; nothing was written")
            if tag == T_ORIG and out_lines[k] != in_lines[i]:
                raise VerifyError(f"{name}:{k + 1}: input line {i + 1} was altered; nothing was "
                                  "written")
            expect += 1
    while expect < len(in_lines) and expect in retimed_lines:
        expect += 1
    if expect != len(in_lines):
        raise VerifyError(f"{name}: input lines from {expect + 1} on are missing; nothing was "
                          "written")
    # the acceleration lines around slowed stretches set limits only
    for k, (tag, _) in enumerate(result.tags):
        if tag == T_ACCEL and not out_lines[k].startswith(_ACCEL_LINE):
            raise VerifyError(f"{name}:{k + 1}: a line we added to set the acceleration is not "
                              "M201, M204, M205 or SET_VELOCITY_LIMIT; nothing was written")
    # 2./3. extrusion and end points, from an independent parse of the output
    out = read_program(result.data, name, flavour=flavour, g91_relative_e=g91_relative_e)
    owner_of_line = {}
    for k, (tag, i) in enumerate(result.tags):
        if tag == T_NEW:
            owner_of_line[k] = i
    n_in = len(program.moves)
    # Python floats, not a numpy array: the same sums, without a numpy scalar per move
    de_sum = [0.0] * n_in
    last_end = {}
    tags = result.tags
    for mv in out.moves:
        i = owner_of_line.get(mv.line_no)
        if i is None:
            if tags[mv.line_no][0] != T_ORIG:
                # only re-timed pieces and untouched input lines may move the machine
                raise VerifyError(f"{name}:{mv.line_no + 1}: a line we added moves the machine; "
                                  "nothing was written")
            continue
        de_sum[i] += mv.e_end_mm - mv.e_start_mm
        last_end[i] = mv.end_mm
    for i in sorted(set(owner_of_line.values())):
        orig = program.moves[i]
        if abs(de_sum[i] - orig.de_mm) > E_TOL_MM:
            raise VerifyError(f"{name}: move on input line {orig.line_no + 1}: extrusion "
                              f"{de_sum[i]:.7f} mm instead of {orig.de_mm:.7f} mm; nothing was "
                              "written")
        end = last_end.get(i)
        oe = orig.end_mm
        if end is None or max(abs(end[0] - oe[0]), abs(end[1] - oe[1]),
                              abs(end[2] - oe[2])) > XYZ_TOL_MM:
            raise VerifyError(f"{name}: move on input line {orig.line_no + 1} no longer ends at "
                              f"{orig.end_mm}; nothing was written")
    # every original move's end point must still be reached, re-timed or not: compare the
    # positions after each original move in the two parses
    if len(out.moves) < n_in:
        raise VerifyError(f"{name}: fewer moves in the output than in the input; nothing was "
                          "written")
    idents = sum(1 for tag, _ in result.tags if tag == T_IDENT)
    if idents != 1:
        raise VerifyError(f"{name}: expected one ident line, wrote {idents}")
    return out


def atomic_write(target: pathlib.Path, data: bytes) -> None:
    """Write ``data`` to ``target`` through a temporary file and os.replace
    (gcode_feedopt.outputs.write_bytes: the one safe-write path)."""
    write_bytes(target, data)
