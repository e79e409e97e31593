import math

import pytest

from gcode_feedopt.errors import GCodeError
from gcode_feedopt.gcode.reader import EXTRUDE, RETRACT, TRAVEL, read_program, split_lines


def rp(text, **kw):
    return read_program(text.encode() if isinstance(text, str) else text, "t.gcode", **kw)


def test_lines_keep_their_endings_and_bytes():
    data = b"G1 X1 F600\r\nG1 X2 ; caf\xe9\nG1 X3"
    lines = split_lines(data)
    assert lines == [b"G1 X1 F600\r\n", b"G1 X2 ; caf\xe9\n", b"G1 X3"]
    prog = read_program(data, "t")
    assert b"".join(prog.lines) == data
    assert [m.end_mm[0] for m in prog.moves] == [1, 2, 3]


def test_binary_bgcode_refused_with_fix():
    with pytest.raises(GCodeError, match="bgcode.*export text G-code"):
        read_program(b"GCDE\x01\x00\x00\x00", "p.bgcode")


def test_g20_refused_naming_line():
    with pytest.raises(GCodeError, match=r"t.gcode:2: G20 \(inches\).*G21"):
        rp("G21\nG20\nG1 X1 F100\n")


def test_relative_xyz_and_marlin_e_modes():
    prog = rp("G1 X10 Y10 F600\nG91\nG1 X5 E1\nG1 Y-2 E1\nG90\nM83\nG1 X0 E0.5\n")
    ends = [m.end_mm[:2] for m in prog.moves]
    assert ends == [(10, 10), (15, 10), (15, 8), (0, 8)]
    # Marlin: G91 makes E relative too, so E goes 0 -> 1 -> 2, then M83 relative 0.5
    assert [round(m.e_end_mm, 9) for m in prog.moves] == [0, 1, 2, 2.5]


def test_klipper_g91_e_semantics():
    # Klipper: G90 restores the M82 absolute E
    prog = rp("M82\nG1 X1 E1 F600\nG91\nG1 X1 E1\nG90\nG1 X3 E5\n", flavour="klipper")
    assert [m.e_end_mm for m in prog.moves] == [1, 2, 5]


def test_g92_offsets_make_no_jump():
    prog = rp("G1 X10 E5 F600\nG92 X0 E0\nG1 X5 E1\n")
    assert prog.moves[1].start_mm[0] == 10 and prog.moves[1].end_mm[0] == 15
    assert prog.moves[1].de_mm == pytest.approx(1.0)


def test_m83_with_g92():
    prog = rp("M83\nG1 X1 E0.5 F600\nG92 E0\nG1 X2 E0.5\n")
    assert [m.de_mm for m in prog.moves] == [0.5, 0.5]


def test_arc_ij_and_r_are_exact():
    prog = rp("G1 X10 Y0 F600\nG3 X0 Y10 I-10 J0\nG2 X10 Y0 R10\n")
    a = prog.moves[1].arc
    assert a.radius_mm == pytest.approx(10) and a.sweep_rad == pytest.approx(math.pi / 2)
    b = prog.moves[2].arc
    assert b.radius_mm == pytest.approx(10) and b.sweep_rad == pytest.approx(-math.pi / 2)
    assert prog.moves[1].xyz_length_mm == pytest.approx(5 * math.pi)


def test_full_circle_with_ij():
    prog = rp("G1 X10 Y0 F600\nG2 X10 Y0 I-10 J0\n")
    assert prog.moves[1].arc.sweep_rad == pytest.approx(-2 * math.pi)


def test_arc_off_circle_refused():
    with pytest.raises(GCodeError, match="not on the circle"):
        rp("G1 X10 Y0 F600\nG3 X0 Y12 I-10 J0\n")


def test_klipper_macros_and_unknown_codes_pass():
    prog = rp("START_PRINT BED=60 EXTRUDER=200\nSET_VELOCITY_LIMIT ACCEL=2000\nG1 X1 F600\n"
              "Q99 nonsense\nG1 X2\n")
    names = [e.name for e in prog.events]
    assert "START_PRINT" in names and "SET_VELOCITY_LIMIT" in names
    sv = [e for e in prog.events if e.name == "SET_VELOCITY_LIMIT"][0]
    assert sv.params["ACCEL"] == 2000 and not sv.stop
    assert len(prog.moves) == 2


def test_fractional_accelerations_are_read_as_the_firmware_reads_them():
    """pygcode reads T (and L, N) as integers and refuses ``M204 P1500 T1500.5``; Marlin reads
    every parameter as a number. Such a line was an unknown command that stops the planner, its
    accelerations lost (the writer's ``M204 P0.25 T0.25`` ran at the file's acceleration)."""
    prog = rp("M204 P1500 T1500.5\nG1 X1 F600\nM204 P0.25 T0.25\nG1 X2\nM117 T1.5 done\n")
    m204 = [e for e in prog.events if e.name == "M204"]
    assert [e.params for e in m204] == [{"P": 1500.0, "T": 1500.5}, {"P": 0.25, "T": 0.25}]
    assert not any(e.stop for e in m204)
    # a line that is not only letter-number words still passes as an unknown command
    assert [e.name for e in prog.events if e.line_no == 4] == ["M117"]
    assert len(prog.moves) == 2


def test_numbered_lines_are_fixed():
    prog = rp("N1 G1 X1 F600*34\nG1 X2\n")
    assert prog.moves[0].fixed and not prog.moves[1].fixed


def test_words_without_values_refused():
    with pytest.raises(GCodeError, match="t.gcode:1"):
        rp("G1 X F600\n")


def test_move_kinds():
    prog = rp("G1 X1 F600\nG1 X2 E1\nG1 E0.5\nG1 Z1\n")
    assert [m.kind for m in prog.moves] == [TRAVEL, EXTRUDE, RETRACT, "zhop"]


def test_empty_and_no_moves():
    with pytest.raises(GCodeError, match="empty"):
        rp("")
    with pytest.raises(GCodeError, match="no G0/G1/G2/G3 moves"):
        rp("M104 S200\n; nothing\n")


def test_absurd_coordinates_refused():
    with pytest.raises(GCodeError, match="beyond"):
        rp("G1 X1000000000 F600\n")


@pytest.mark.parametrize("fast", [True, False])
def test_numbers_end_at_the_next_letter_as_the_firmware_reads_them(fast):
    # Marlin's value_float cuts a value at E and Klipper splits a line at every letter:
    # X1e1 is X1 and E1 to both, as compact G1X10E1 is X10 and E1; the old reader took
    # 1e1 as 10 (moved to X10 and extruded the E1 pygcode also gave)
    prog = read_program(b"M83\nG1 X1e1 F600\nG1X10E1\n", "t.gcode", fast=fast)
    assert [m.end_mm[0] for m in prog.moves] == [1.0, 10.0]
    assert [m.words["E"] for m in prog.moves] == ["1", "1"]


@pytest.mark.parametrize("line", [b"G92 E1e10", b"G1 X1 X2 F600", b"M204 P1e3 P2000"])
def test_a_word_given_twice_is_refused(line):
    with pytest.raises(GCodeError, match="appears twice") as exc:
        read_program(line + b"\nG1 X1 F600\n", "t.gcode")
    assert str(exc.value).startswith("t.gcode:1: ")
    assert ("exponent" in str(exc.value)) == (b"e" in line.lower().split(b" ", 1)[1])
