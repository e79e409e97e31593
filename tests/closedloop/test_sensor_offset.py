"""The sensor's zero and logs misread on the way in (``closedloop.logs``): an encoder that
counts from its own zero is subtracted, not diagnosed; a constant the log cannot tell from a
gain is said and left; a log in µm, inches, with a reversed encoder or swapped columns is
refused with that cause."""

import re
import warnings

import numpy as np
import pytest
from click.testing import CliRunner
from scipy import signal

from gcode_feedopt.cli import cli
from gcode_feedopt.closedloop.diagnose import diagnose_log
from gcode_feedopt.closedloop.logs import MotionLog, load_log, log_warmup, sensor_offsets
from gcode_feedopt.errors import LogError, LogWarning
from gcode_feedopt.profile import save_profile

from ..conftest import INDEPENDENT_DIR, bench_a_log


def _residual(n, rms_mm, seed):
    """Coloured residual: white noise through a lightly damped 40 Hz resonance (Ts 2 ms),
    as a twin's dynamic error rings."""
    rng = np.random.default_rng(seed)
    b, a = signal.iirpeak(40.0, 4.0, fs=500.0)
    e = signal.lfilter(b, a, rng.standard_normal(n))
    return rms_mm * e / np.std(e)


def _path(centre, half_span):
    """Commanded positions (Ts 2 ms): 0.4 s at rest at three places with moves between
    (sinusoidal, 1.2 s each); the mask of moving samples."""
    rest, move = 200, 600
    u = 0.5 - 0.5 * np.cos(np.pi * np.arange(move) / move)
    a, b, c = centre - half_span, centre + half_span, centre
    cmd = np.concatenate([np.full(rest, a), a + (b - a) * u, np.full(rest, b),
                          b + (c - b) * u, np.full(rest, c)])
    moving = np.concatenate([np.zeros(rest), np.ones(move), np.zeros(rest), np.ones(move),
                             np.zeros(rest)]).astype(bool)
    return cmd, moving


@pytest.mark.parametrize("seed", range(5))
def test_sensor_offsets_tell_an_offset_from_a_scale_and_a_lag(seed):
    """Rests at 70, 150 and 110 mm with moves between; the twin's mean settled at rest; a
    residual that rings at 20 µm RMS while moving and is 0.5 µm of sensor noise at rest:
    a 50 µm offset is found to 1 µm; a 0.4 % gain (r = 0.004·x̂) is not taken for one;
    a lag of −0.15 mm while moving that vanishes at rest (a delay on a one-way stretch) is not
    one; the residual alone has none; a 30 µm offset on a path spanning 2 mm at 110 mm is
    "either" (an offset or a scale of 1 − 0.03/110 fit it alike)."""
    wide, moving = _path(110.0, 40.0)
    narrow, _ = _path(110.0, 1.0)
    rng = np.random.default_rng(100 + seed)
    r = np.where(moving, _residual(wide.size, 0.020, seed), 0.0)
    r = r + rng.normal(0.0, 0.0005, wide.size)

    def verdict(cmd, extra):
        return sensor_offsets((cmd + r + extra)[:, None], cmd[:, None], cmd[:, None])[0]

    v, o, _ = verdict(wide, 0.05)
    assert v == "offset" and abs(o - 0.05) < 0.001
    assert verdict(wide, 0.004 * wide)[0] == ""
    assert verdict(wide, np.where(moving, -0.15, 0.0))[0] == ""
    assert verdict(wide, 0.0)[0] == ""
    assert verdict(narrow, 0.03)[0] == "either"


def test_bench_a_logs_carry_no_sensor_offset(bench_a):
    """Every benchA log (its position at rest is its command, DC gain 1) is read as measured:
    no offset subtracted, no constant said to be ambiguous — the gain log (log_10, y × 1.004)
    included. The 476 logs of seeds 0–67 of tests/foreign/machines.py: nothing subtracted,
    "either" on 3, each a gain log (seeds 12, 16, 19)."""
    prof, labels = bench_a
    for e in labels["logs"]:
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            log = load_log(INDEPENDENT_DIR / e["file"], prof)
        assert "sensor_offset_mm" not in log.info, e["file"]
        assert not [w for w in rec if "sensor" in str(w.message) or "cannot tell" in
                    str(w.message)], e["file"]


def _shifted(tmp_path, name, dx, dy):
    a = np.loadtxt(INDEPENDENT_DIR / "logs" / name, delimiter=",", skiprows=1)
    a[:, 3] += dx
    a[:, 4] += dy
    p = tmp_path / name
    np.savetxt(p, a, delimiter=",", fmt="%.6f", header="t,x_cmd,y_cmd,x,y", comments="")
    return p


def _as_read(name, prof, dx=0.0, dy=0.0):
    """The benchA log as a MotionLog with the offsets left in (what load_log read before)."""
    cmd, pos = bench_a_log(name)
    pos = pos + [dx, dy]
    z = np.zeros((len(cmd), 1))
    return MotionLog(ts_s=prof.ts_s, cmd_mm=np.hstack([cmd, z]), pos_mm=np.hstack([pos, z]),
                     source=name, kind="encoder", warmup=log_warmup(cmd, prof.ts_s, prof))


def test_an_encoder_zero_is_subtracted_not_diagnosed(bench_a, tmp_path):
    """benchA's clean butterfly with the encoders zeroed 0.05 mm (x) and −0.03 mm (y) off the
    machine's: left in, the diagnosis named backlash x 0.012 mm; read by load_log, both
    offsets are subtracted (read at rest, to 1 µm: +0.04997, −0.03055 — half the encoder's
    1.25 µm quantum; one warning) and the diagnosis is none. The gain log with
    x's encoder off: x subtracted, y's gain (1.004) still named, to 0.1 %."""
    prof, _ = bench_a
    assert diagnose_log(_as_read("log_01.csv", prof, 0.05, -0.03), prof).effects[0]["kind"] \
        != "none"
    with pytest.warns(LogWarning, match=r"sit off the commanded ones by a constant "
                      r"\(x by \+0\.0(500|499) mm, y by -0\.030\d mm\)"):
        log = load_log(_shifted(tmp_path, "log_01.csv", 0.05, -0.03), prof)
    got = log.info["sensor_offset_mm"]
    assert abs(got["x"] - 0.05) < 1e-3 and abs(got["y"] + 0.03) < 1e-3
    _, pos = bench_a_log("log_01.csv")
    np.testing.assert_allclose(log.pos_mm[:, :2], pos, atol=1e-3)
    assert [e["kind"] for e in diagnose_log(log, prof).effects] == ["none"]

    with pytest.warns(LogWarning, match=r"constant \(x by \+0\.0(500|499) mm\)"):
        log = load_log(_shifted(tmp_path, "log_10.csv", 0.05, 0.0), prof)
    effects = diagnose_log(log, prof).effects
    assert [(e["kind"], e["axis"]) for e in effects] == [("gain", "y")]
    assert effects[0]["params"]["scale"] == pytest.approx(1.004, abs=0.001 * 0.004 + 4e-6)


def test_predict_reads_the_log_in_the_machines_frame(bench_a, tmp_path):
    """`predict` on the shifted butterfly says the offsets and reports what it reports on the
    log as recorded: the same RMS per axis (0.63 / 0.64 µm), coverage within 0.5 % (95.8 /
    96.3 % vs 95.9 / 96.4 %: the offset is read to the encoder's 1.25 µm quantum)."""
    prof, _ = bench_a
    yaml = save_profile(prof, tmp_path / "benchA.yaml")
    runner = CliRunner()
    out, said = {}, {}
    for tag, path in (("as is", INDEPENDENT_DIR / "logs" / "log_01.csv"),
                      ("shifted", _shifted(tmp_path, "log_01.csv", 0.05, -0.03))):
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            res = runner.invoke(cli, ["predict", str(path), "--machine", str(yaml),
                                      "-o", str(tmp_path / f"{tag}.csv")])
        assert res.exit_code == 0, res.output
        out[tag] = res.output
        said[tag] = [str(w.message) for w in rec if "sensor's zero" in str(w.message)]
    assert len(said["shifted"]) == 1 and not said["as is"]
    got = {tag: re.findall(r"(\w) RMS ([\d.]+) µm, 95 % interval holds ([\d.]+)%", text)
           for tag, text in out.items()}
    assert len(got["as is"]) == len(got["shifted"]) == 2
    for (ax0, rms0, cov0), (ax1, rms1, cov1) in zip(got["as is"], got["shifted"]):
        assert ax0 == ax1 and rms0 == rms1 and abs(float(cov0) - float(cov1)) <= 0.5


@pytest.mark.parametrize("how, cause", [
    ("um", r"measured x is 1000× the command: in µm\? write mm"),
    ("inch", r"measured x is 0\.03937× the command: in inches\? write mm"),
    ("flip", r"measured x runs against the command \(-1×\): the encoder counts the other way"),
    ("swap", r"measured x follows the commanded y \(1×\): are the x and y columns swapped\?"),
])
def test_a_misread_log_is_refused_with_its_cause(bench_a, tmp_path, how, cause):
    """A log in the wrong units, with x's encoder counting backwards or x and y swapped is
    refused in one line naming that (not only "wrong machine or a broken sensor"), the file
    untouched."""
    prof, _ = bench_a
    a = np.loadtxt(INDEPENDENT_DIR / "logs" / "log_01.csv", delimiter=",", skiprows=1)
    if how == "um":
        a[:, 3:5] *= 1000
    elif how == "inch":
        a[:, 3:5] /= 25.4
    elif how == "flip":
        a[:, 3] = 220 - a[:, 3]
    else:
        a[:, [3, 4]] = a[:, [4, 3]]
    p = tmp_path / f"{how}.csv"
    np.savetxt(p, a, delimiter=",", fmt="%.6f", header="t,x_cmd,y_cmd,x,y", comments="")
    before = p.read_bytes()
    with pytest.raises(LogError, match=r"misses axis x by .*" + cause) as exc:
        load_log(p, prof)
    assert "\n" not in str(exc.value) and p.read_bytes() == before
