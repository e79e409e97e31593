"""The bad-input corpus: every case is answered by a clear one-line error (non-zero exit,
the input untouched) or by a correct pass-through."""

import os

import pytest
from click.testing import CliRunner

from gcode_feedopt.cli import cli

OK, ERR = "ok", "error"

GOOD_TAIL = b"G1 X10 Y10 F3000\nG1 X50 Y10 E2 F1200\nG1 X50 Y50 E4\n"

CASES = {
    "empty": (b"", ERR, "empty"),
    "whitespace only": (b"  \n\n", ERR, "empty"),
    "binary": (b"\x00\x01\x02\x03" * 100, ERR, "NUL bytes"),
    "bgcode": (b"GCDE\x01\x00\x00\x00\x01\x00", ERR, "bgcode"),
    "no moves": (b"M104 S200\nM140 S60\n", ERR, "no G0/G1/G2/G3"),
    "only extruder moves": (b"G1 E5 F300\nG1 E-1\n", ERR, "no move travels"),
    "g20 inches": (b"G20\n" + GOOD_TAIL, ERR, "G20"),
    "word without value": (b"G1 X F300\n" + GOOD_TAIL, ERR, "cannot read the motion"),
    "feed zero": (b"G1 X1 F0\n" + GOOD_TAIL, ERR, "must be positive"),
    # 1e-30 written out: an exponent is read as the firmware reads it, F1 then E-30
    "feed 1e-30": (b"G1 X1 F0." + b"0" * 29 + b"1\n" + GOOD_TAIL, ERR, "below 0.1 mm/min"),
    "feed with an exponent": (b"G1 X1 E1 F1e-30\n" + GOOD_TAIL, ERR, "E appears twice"),
    "no feed at all": (b"G1 X1 Y1\nG1 X2 Y2 E1\n", ERR, "without any feed"),
    "absurd coordinates": (b"G1 X99999999 F300\n" + GOOD_TAIL, ERR, "beyond"),
    "nan coordinate": (b"G1 Xnan F300\n" + GOOD_TAIL, ERR, ""),
    "arc off circle": (b"G1 X10 Y0 F600\nG2 X0 Y13 I-10 J0\n", ERR, "not on the circle"),
    "arc radius too small": (b"G1 X0 Y0 F600\nG2 X20 Y0 R5\n", ERR, "smaller than half"),
    "arc without centre": (b"G1 X0 Y0 F600\nG2 X20 Y0\n", ERR, "needs I/J or R"),
    "arc plane G18": (b"G18\n" + GOOD_TAIL, ERR, "arc plane"),
    # Marlin and Klipper reject a line of bare axis words as an unknown command (no modal
    # motion), so it passes through untouched and moves nothing
    "axis words without G": (b"G1 X0 F600\nX10 Y10\n" + GOOD_TAIL, OK, None),
    "truncated last line": (GOOD_TAIL + b"G1 X60 Y6", OK, None),
    "crlf": (GOOD_TAIL.replace(b"\n", b"\r\n"), OK, None),
    "non-utf8 comment": (b"; caf\xe9 \xff\xfe\n" + GOOD_TAIL, OK, None),
    "klipper macros": (b"START_PRINT BED=60 EXTRUDER=210\nSET_VELOCITY_LIMIT ACCEL=2500\n"
                       + GOOD_TAIL + b"END_PRINT\n", OK, None),
    "g91 moves": (b"G1 X0 Y0 F3000\nG91\nG1 X10 E1\nG1 Y10 E1\nG90\n", OK, None),
    "m83 with g92": (b"M83\nG92 E0\nG1 X0 Y0 F3000\nG1 X10 E0.5\nG92 E0\nG1 Y10 E0.5\n", OK, None),
    "arcs with r": (b"G1 X0 Y0 F600\nG2 X20 Y0 R10 E1\nG3 X0 Y0 R-10 E2\n", OK, None),
    "line numbers with checksums": (b"N1 G1 X0 Y0 F600*120\nN2 G1 X10 Y0*26\n" + GOOD_TAIL, OK, None),
    "unknown codes": (b"G1 X0 F600\nM9999 Q1\nG12345\nB1\n" + GOOD_TAIL, OK, None),
    "paren comments": (b"(header)\nG1 X0 (go) Y0 F600\n" + GOOD_TAIL, OK, None),
    "tool change": (GOOD_TAIL + b"T1\nG1 X0 Y0 E5 F600\n", OK, None),
    "firmware retraction": (GOOD_TAIL + b"G10\nG0 X0 Y0\nG11\nG1 X5 E6\n", OK, None),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_bad_input_corpus(name, tmp_path):
    data, expect, match = CASES[name]
    src = tmp_path / "in.gcode"
    src.write_bytes(data)
    mtime = os.stat(src).st_mtime_ns
    out = tmp_path / "out.gcode"
    res = CliRunner().invoke(cli, [str(src), "-o", str(out), "--machine", "ender3pro", "-q"])
    assert src.read_bytes() == data and os.stat(src).st_mtime_ns == mtime
    if expect == ERR:
        assert res.exit_code != 0, res.output
        msg = res.output.strip()
        assert msg.count("\n") == 0, msg  # one line
        assert "error:" in msg and match.lower() in msg.lower()
        assert not out.exists()
    else:
        assert res.exit_code == 0, res.output
        assert out.exists()


def test_in_place_edit_is_atomic_and_refuses_on_error(tmp_path):
    src = tmp_path / "part.gcode"
    src.write_bytes(b"G20\n" + GOOD_TAIL)
    res = CliRunner().invoke(cli, ["--machine", "ender3pro", str(src)])
    assert res.exit_code != 0 and src.read_bytes() == b"G20\n" + GOOD_TAIL
    assert [p.name for p in tmp_path.iterdir()] == ["part.gcode"]  # no temp left behind
    src.write_bytes(GOOD_TAIL)
    res = CliRunner().invoke(cli, ["--machine", "ender3pro", str(src)])
    assert res.exit_code == 0 and b"processed by gcode-feedopt" in src.read_bytes()


def test_unknown_machine_suggests():
    res = CliRunner().invoke(cli, ["x.gcode", "--machine", "ender3"])
    assert res.exit_code != 0 and "did you mean 'ender3pro'" in res.output


def test_closed_stdout_is_not_an_internal_error():
    """`gcode-feedopt profile show P | head -1`: the reader goes away; we stop quietly and
    non-zero (click's exit 1 for EPIPE), never with "internal error"."""
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-m", "gcode_feedopt", "profile", "show",
                          "ender3pro"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()  # before the command writes (it is still importing)
    err = p.stderr.read()
    assert p.wait() in (1, 141), err
    assert b"internal error" not in err and b"Traceback" not in err
