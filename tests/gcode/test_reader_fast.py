"""The reader's fast path (plain G0/G1 lines by a regular expression) against pygcode: the
same Program — moves with their word texts, events, errors — on every real file and on
generated lines that sit on and around the fast path's edge."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gcode_feedopt.errors import GCodeError
from gcode_feedopt.gcode.reader import read_program

from ..conftest import GCODE_DIR, REPO

FILES = sorted(GCODE_DIR.glob("*.gcode")) + sorted((REPO / "sample_gcode").glob("*.gcode"))


def _same(data: bytes, **kw):
    """Both readers give the same Program, or the same error."""
    try:
        fast = read_program(data, "t.gcode", fast=True, **kw)
    except GCodeError as e:
        with pytest.raises(GCodeError) as slow_err:
            read_program(data, "t.gcode", fast=False, **kw)
        assert str(slow_err.value) == str(e)
        return None
    slow = read_program(data, "t.gcode", fast=False, **kw)
    assert fast.moves == slow.moves
    assert [m.words for m in fast.moves] == [m.words for m in slow.moves]
    assert fast.events == slow.events
    assert fast.lines == slow.lines and fast.processed_line == slow.processed_line
    return fast


@pytest.mark.parametrize("src", FILES, ids=lambda p: p.name)
def test_real_files_same_program(src):
    if not src.exists():
        pytest.skip(f"{src} not found")
    prog = _same(src.read_bytes())
    assert prog is not None and prog.moves


num = st.one_of(
    st.floats(-300, 300, allow_nan=False).map(lambda v: f"{v:.{abs(hash(v)) % 6}f}"),
    st.sampled_from(["0", "-0", ".5", "-.5", "5.", "-5.", "10", "+1", "1e2", "1E-1", "",
                     "00.100", "nan", "1.2.3", "-", "."]))
letter = st.sampled_from(list("XYZEFXYZEF") + ["x", "e", "f", "I", "J", "R", "S", "T", "N", "M"])
sep = st.sampled_from([" ", " ", " ", "  ", "", "\t"])
head = st.sampled_from(["G1", "G0", "G01", "G00", "G1", "G1", "g1", "G2", "G3", "G92", "G1.0",
                        "G10", "G11", "G4", " G1", "N7 G1", "M83", "M82", "G91", "G90", "X1"])
tail = st.sampled_from(["", "", " ", " ;c", ";c", " ; (x) *9", " (p)", "*12", " \r", "\t"])


@st.composite
def line(draw):
    words = draw(st.lists(st.tuples(sep, letter, num), max_size=5))
    return draw(head) + "".join(s + L + v for s, L, v in words) + draw(tail)


good_num = st.one_of(st.floats(-300, 300, allow_nan=False).map(lambda v: f"{v:.{abs(hash(v)) % 6}f}"),
                     st.sampled_from(["0", "-0", ".5", "-.5", "5.", "00.100"]))


@st.composite
def plain_line(draw):
    """On the fast path (or a hair off it: a bad value, a duplicate or out-of-place word)."""
    words = draw(st.lists(st.tuples(st.sampled_from("XYZEF"), good_num), max_size=5))
    text = draw(st.sampled_from(["G1", "G0", "G01"])) + "".join(f" {L}{v}" for L, v in words)
    if draw(st.integers(0, 9)) == 0:
        text += " " + draw(letter) + draw(num)
    return text + draw(st.sampled_from(["", " ", " ; c", ";(c)*3"]))


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(line(), plain_line()), min_size=1, max_size=12), st.sampled_from(["\n", "\r\n"]),
       st.sampled_from([("marlin", True), ("marlin", False), ("klipper", True)]))
def test_generated_lines_same_program(lines, ending, fw):
    data = ("G1 X1 Y1 F600" + ending + ending.join(lines) + ending).encode()
    _same(data, flavour=fw[0], g91_relative_e=fw[1])


def test_new_move_is_the_dataclass_instance():
    """The reader builds moves without the frozen dataclass's __init__ (for speed): the
    instance is the one ``Move(...)`` gives — fields, equality, hash, repr, immutability."""
    import dataclasses

    from gcode_feedopt.gcode.reader import Arc, Move, _new_move

    vals = (7, "G2", (1.0, 2.0, 0.2), (3.0, 2.0, 0.2), 0.5, 0.75, 30.0,
            Arc(center_mm=(2.0, 2.0), cw=True, sweep_rad=-3.14159, radius_mm=1.0), "extrude", 3,
            False, True, (0.0, 0.0, 0.0, -1.5), False, {"X": "3", "E": ".25"}, "outer_wall")
    a, b = _new_move(*vals), Move(*vals)
    assert a == b and hash(a) == hash(b) and repr(a) == repr(b)
    assert vars(a) == vars(b) and a.words == b.words and a.de_mm == b.de_mm
    with pytest.raises(dataclasses.FrozenInstanceError):
        a.line_no = 8
