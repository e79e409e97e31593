"""Every numeric option of every sub-command: NaN, infinities, zero, negatives, huge and tiny
values and non-numbers are one line, exit 2, naming the option and the accepted range; the
boundary values run; values that would make a plan absurdly large are refused with the limit."""

from __future__ import annotations

import pathlib

import pytest
from click.testing import CliRunner
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gcode_feedopt.cli import cli
from gcode_feedopt.cli.options import LIMITS

REPO = pathlib.Path(__file__).resolve().parents[1]
GOOD = b"G1 X10 Y10 F3000\nG1 X50 Y10 E2 F1200\nG1 X50 Y50 E4\n"

#: (sub-command argv before the option, option, LIMITS key)
NUMERIC = [
    (["IN", "-o", "OUT", "-m", "ender3pro"], "--vmax", "vmax"),
    (["IN", "-o", "OUT", "-m", "ender3pro"], "--amax", "amax"),
    (["IN", "-o", "OUT", "-m", "ender3pro"], "--tolerance", "tolerance"),
    (["IN", "-o", "OUT", "-m", "ender3pro"], "--stringency", "stringency"),
    (["batch", "DIR", "-m", "ender3pro"], "--vmax", "vmax"),
    (["batch", "DIR", "-m", "ender3pro"], "--amax", "amax"),
    (["batch", "DIR", "-m", "ender3pro"], "--tolerance", "tolerance"),
    (["batch", "DIR", "-m", "ender3pro"], "--stringency", "stringency"),
    (["compare", "IN", "-m", "ender3pro"], "--vmax", "vmax"),
    (["compare", "IN", "-m", "ender3pro"], "--amax", "amax"),
    (["compare", "IN", "-m", "ender3pro"], "--tolerance", "tolerance"),
    (["compare", "IN", "-m", "ender3pro"], "--stringency", "stringency"),
    (["compare", "IN", "-m", "ender3pro"], "--seed", "seed"),
    (["simulate", "IN", "-m", "ender3pro"], "--seed", "seed"),
    (["simulate", "IN", "-m", "ender3pro"], "--tolerance", "tolerance"),
    (["diagnose", "IN", "-m", "ender3pro"], "--fit-fraction", "fit_fraction"),
    (["identify", "--x", "IN", "-o", "OUT.yaml", "--excitation", "legacy"], "--freq-start",
     "freq_hz"),
    (["identify", "--x", "IN", "-o", "OUT.yaml", "--excitation", "legacy"], "--freq-end",
     "freq_hz"),
    (["identify", "--x", "IN", "-o", "OUT.yaml", "--excitation", "legacy"], "--hz-per-sec",
     "hz_per_sec"),
    (["identify", "--x", "IN", "-o", "OUT.yaml", "--excitation", "legacy"], "--accel-per-hz",
     "accel_per_hz"),
    (["identify", "--x", "IN", "-o", "OUT.yaml", "--excitation", "current"],
     "--sweeping-accel", "sweeping_accel"),
    (["identify", "--x", "IN", "-o", "OUT.yaml", "--excitation", "current"],
     "--sweeping-period", "sweeping_period"),
]
BAD = ["nan", "NaN", "inf", "-inf", "-5", "1e308", "-1e308", "abc", "", "1e400", "0x10",
       "9" * 400]


def argv(template, tmp_path):
    src = tmp_path / "in.gcode"
    src.write_bytes(GOOD)
    (tmp_path / "jobs").mkdir(exist_ok=True)
    sub = {"IN": str(src), "OUT": str(tmp_path / "out.gcode"), "DIR": str(tmp_path / "jobs"),
           "OUT.yaml": str(tmp_path / "out.yaml")}
    return [sub.get(a, a) for a in template]


def assert_one_line_usage(res, option):
    assert res.exit_code == 2, (res.exit_code, res.output)
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    msg = res.output.strip()
    assert "\n" not in msg and len(msg) <= 300, msg
    assert msg.startswith("gcode-feedopt: error:") and option in msg, msg


def out_of_range(key):
    lo, hi, _ = LIMITS[key]
    vals = [lo - (1 if isinstance(lo, int) else 1e-3 * max(abs(lo), 1e-3)),
            hi * 10 + 1]
    if key not in ("seed",):
        vals.append(0 if lo > 0 else None)
    return [v for v in vals if v is not None and not (lo <= v <= hi)]


CASES = [(t, o, k, v) for t, o, k in NUMERIC for v in BAD + [repr(x) for x in out_of_range(k)]]


@pytest.mark.parametrize("template,option,key,value", CASES,
                         ids=[f"{t[0] if t[0] != 'IN' else 'optimize'}{o}={v[:12]}"
                              for t, o, k, v in CASES])
def test_bad_numeric_option_is_one_line(tmp_path, template, option, key, value):
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    res = CliRunner().invoke(cli, argv(template, tmp_path) + [option, value])
    assert_one_line_usage(res, option)
    after = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    assert set(after) - set(before) <= {"in.gcode"}  # nothing written


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(value=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(),
                       st.text(max_size=30)),
       which=st.sampled_from(NUMERIC))
def test_fuzz_numeric_options_never_a_traceback(tmp_path, value, which):
    """Any value: refused in one line, or accepted (then the missing input is the error)."""
    template, option, key = which
    args = [a if a not in ("IN", "DIR") else str(tmp_path / "missing") for a in template]
    args = [a if a not in ("OUT", "OUT.yaml") else str(tmp_path / "o.yaml") for a in args]
    text = str(value)
    res = CliRunner().invoke(cli, args + [option, text])
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    assert res.exit_code == 2, res.output
    msg = res.output.strip()
    assert "\n" not in msg and len(msg) <= 300 and msg.startswith("gcode-feedopt: error:"), msg


@pytest.mark.parametrize("method", ["kinematic", "pb"])
@pytest.mark.parametrize("extra", [["--vmax", "0.1"], ["--vmax", "5000"], ["--amax", "1"],
                                   ["--amax", "1e6"], ["--tolerance", "10"],
                                   ["--stringency", "0.5"], ["--stringency", "0.9999"]])
def test_boundary_values_run(tmp_path, method, extra):
    src = tmp_path / "in.gcode"
    src.write_bytes(GOOD)
    res = CliRunner().invoke(cli, [str(src), "-o", str(tmp_path / "out.gcode"), "-m",
                                   "ender3pro", "--method", method, "-q", "--allow-slower",
                                   *extra])
    assert res.exit_code == 0, res.output
    assert b"processed by gcode-feedopt" in (tmp_path / "out.gcode").read_bytes()
    assert src.read_bytes() == GOOD


def test_absurd_plan_size_is_refused_with_the_limit(tmp_path):
    """--vmax 0.1 on a 125 m Benchy: 347 h of 2 ms samples; refused before planning."""
    from .conftest import GCODE_DIR

    benchy = GCODE_DIR / "cura-4.11_ender3_3dbenchy.gcode"
    if not benchy.is_file():
        pytest.skip("no Benchy")
    res = CliRunner().invoke(cli, [str(benchy), "-o", str(tmp_path / "o.gcode"), "-m",
                                   "ender3pro", "--vmax", "0.1"])
    assert res.exit_code == 2, res.output
    msg = res.output.strip()
    assert "\n" not in msg and "above the limit of 3e+07" in msg and "raise --vmax" in msg
    assert list(tmp_path.iterdir()) == []


def test_bad_jobs_environment_is_one_line(tmp_path, monkeypatch):
    from gcode_feedopt.errors import UsageError
    from gcode_feedopt.optimize import parallel

    monkeypatch.setenv("GCODE_FEEDOPT_JOBS", "abc")
    with pytest.raises(UsageError, match="GCODE_FEEDOPT_JOBS='abc' is not a whole number"):
        parallel.default_workers()


def test_compare_methods_empty(tmp_path):
    src = tmp_path / "in.gcode"
    src.write_bytes(GOOD)
    for value in ("", ",", "fast"):
        res = CliRunner().invoke(cli, ["compare", str(src), "-m", "ender3pro", "--methods", value])
        assert_one_line_usage(res, "--methods")


def test_identify_freq_end_below_start(tmp_path):
    src = tmp_path / "in.csv"
    src.write_text("#time,accel_x,accel_y,accel_z\n")
    res = CliRunner().invoke(cli, ["identify", "--x", str(src), "-o", str(tmp_path / "o.yaml"),
                                   "--excitation", "legacy", "--freq-start", "50",
                                   "--freq-end", "10"])
    assert_one_line_usage(res, "--freq-end")
