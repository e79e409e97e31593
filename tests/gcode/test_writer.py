"""Writer invariants: same part, same extrusion, untouched lines byte for byte."""

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gcode_feedopt.gcode.reader import IDENT_PREFIX
from gcode_feedopt.gcode.writer import T_NEW

from .helpers import run


def moves_equal_ends(prog, out):
    """Every original move's end point and E are reached in the output, in order."""
    targets = [(m.end_mm, m.e_end_mm) for m in prog.moves]
    got = [(m.end_mm, m.e_end_mm) for m in out.moves]
    j = 0
    for tgt in targets:
        while j < len(got) and not (np.allclose(got[j][0], tgt[0], atol=1e-9)
                                    and abs(got[j][1] - tgt[1]) <= 1e-6):
            j += 1
        assert j < len(got), f"end point {tgt} never reached"
        j += 1


def test_simple_file_round_trip():
    src = b"; hello\r\nG90\r\nM82\r\nG1 X10 Y10 F3000\r\nG1 X60 Y10 E2.5 F1200 ; wall\r\nM106 S255\r\nG1 X60 Y60 E5\r\n"
    prog, path, sched, res, out = run(src)
    lines = res.data.split(b"\n")
    assert lines[1].startswith(IDENT_PREFIX)
    assert b"; wall" in res.data and b"M106 S255\r\n" in res.data
    assert all(l.endswith(b"\r") for l in lines[:-1])  # CRLF kept on new lines too
    moves_equal_ends(prog, out)
    assert sched.duration_s > 0


def test_relative_e_split_is_exact():
    src = b"M83\nG1 X0 Y0 F6000\nG1 X100 Y0 E3.33333 F600\nG1 X100 Y100 E3.33333\n"
    prog, path, sched, res, out = run(src, mode="sampled")
    news = [m for m in out.moves if m.de_mm != 0]
    assert len(news) > 10
    assert math.isclose(sum(m.de_mm for m in news), 6.66666, abs_tol=1e-9)
    moves_equal_ends(prog, out)


def test_modal_feed_restored_before_untouched_move():
    # the numbered move is left alone and relies on the modal F of 600 mm/min
    src = b"G1 X0 Y0 F600\nG1 X50 Y0\nN5 G1 X60 Y0*99\n"
    prog, path, sched, res, out = run(src)
    text = res.data.decode()
    idx = text.index("N5 G1")
    assert "G1 F600" in text[:idx].splitlines()[-1]
    assert out.moves[-1].feed_mm_s == pytest.approx(10.0)


def test_arcs_stay_arcs_and_end_exactly():
    src = b"G1 X10 Y0 F600\nG3 X-10 Y0 I-10 J0 E3 F1200\nG2 X10 Y0 R10 E6\n"
    prog, path, sched, res, out = run(src, mode="sampled")
    arcs = [m for m in out.moves if m.arc is not None]
    assert len(arcs) > 4
    for m in arcs:
        assert m.arc.radius_mm == pytest.approx(10, abs=2e-3)
    moves_equal_ends(prog, out)


def test_lines_per_second_cap():
    src = b"G1 X0 Y0 F600\n" + b"".join(f"G1 X{100 * (k % 2)} Y{k} E{k} F9000\n".encode()
                                         for k in range(1, 6))
    prog, path, sched, res, out = run(src)
    pieces = [m for m in out.moves if m.e_end_mm > 0]
    # no re-timed piece shorter than 1/max_lines_per_s unless it is a whole original move
    cap = 1.0 / 300.0
    for m in pieces:
        d = math.dist(m.start_mm, m.end_mm)
        assert d / m.feed_mm_s >= cap * 0.5 or d < 1.0


def test_time_metadata_rewritten():
    src = b";FLAVOR:Marlin\n;TIME:9999\nG1 X0 Y0 F600\nG1 X100 Y0 E5\n;TIME_ELAPSED:9999.0\n" \
          b"M73 P50 R10\n; estimated printing time (normal mode) = 1h 2m 3s\n"
    prog, path, sched, res, out = run(src)
    text = res.data.decode()
    total = sched.duration_s
    assert f";TIME:{int(round(total))}\n" in text
    assert "; estimated printing time (normal mode) = 1h" not in text
    assert "M73 P100 R0" in text


coord = st.floats(0, 200, allow_nan=False).map(lambda v: round(v, 3))


@st.composite
def gcode_files(draw):
    rel_e = draw(st.booleans())
    lines = ["G90", "M83" if rel_e else "M82", "G92 E0", "G1 X100 Y100 Z0.2 F6000"]
    x, y, e = 100.0, 100.0, 0.0
    for _ in range(draw(st.integers(1, 25))):
        kind = draw(st.sampled_from(["line", "line", "arc", "travel", "retract"]))
        f = draw(st.sampled_from(["", " F1200", " F3000", " F9000"]))
        if kind == "retract":
            de = -draw(st.floats(0.1, 2).map(lambda v: round(v, 4)))
            e += de
            lines.append(f"G1 E{de if rel_e else round(e, 5)} F2400")
            continue
        if kind == "arc":
            r = draw(st.floats(2, 30).map(lambda v: round(v, 3)))
            ang = draw(st.floats(0.2, 3.0))
            cx, cy = x - r, y  # centre to the left
            nx, ny = cx + r * math.cos(ang), cy + r * math.sin(ang)
            nx, ny = round(nx, 3), round(ny, 3)
            de = round(0.03 * r * ang, 5)
            e += de
            ev = de if rel_e else round(e, 5)
            lines.append(f"G3 X{nx} Y{ny} I{-r} J0 E{ev}{f}")
            # the end point is rounded: recompute the radius check tolerance in the reader
            x, y = nx, ny
            continue
        nx, ny = draw(coord), draw(coord)
        if kind == "travel":
            lines.append(f"G0 X{nx} Y{ny}{f}")
        else:
            de = round(0.03 * math.hypot(nx - x, ny - y), 5)
            e += de
            lines.append(f"G1 X{nx} Y{ny} E{de if rel_e else round(e, 5)}{f}")
        x, y = nx, ny
    return ("\n".join(lines) + "\n").encode()


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(gcode_files(), st.sampled_from(["refeed", "sampled"]))
def test_property_same_part_same_extrusion(data, mode):
    prog, path, sched, res, out = run(data, mode=mode)
    moves_equal_ends(prog, out)
    assert math.isclose(out.moves[-1].e_end_mm, prog.moves[-1].e_end_mm, abs_tol=1e-6)
    # every untouched input line appears, byte for byte, in order
    untouched = [l for i, l in enumerate(prog.lines)
                 if i not in {prog.moves[j].line_no for t, j in res.tags if t == T_NEW}]
    it = iter(res.data.splitlines(keepends=True))
    for l in untouched:
        for o in it:
            if o == l:
                break
        else:
            raise AssertionError(f"line {l!r} lost")
    # the plan never stands still longer than its stops need and ends at the path's end
    assert sched.s_mm[-1] == pytest.approx(path.total_length_mm)
    assert np.all(np.diff(sched.s_mm) >= -1e-12)
