"""Log reading and refusal of bad logs; the observer; diagnose CLI end to end."""

import json

import numpy as np
import pytest
from click.testing import CliRunner

from gcode_feedopt.cli import cli
from gcode_feedopt.closedloop.logs import load_log, observer_position
from gcode_feedopt.closedloop.motion import point_to_point
from gcode_feedopt.errors import LogError
from gcode_feedopt.profile import load_profile
from gcode_feedopt.vm import effects as fx
from gcode_feedopt.vm.log import write_log
from gcode_feedopt.vm.plant import Plant
from gcode_feedopt.vm.trajectory import Trajectory

PROFILE = load_profile("ender3pro")
TS = PROFILE.ts_s


def make_log(path, effects=(), seconds=8.0, seed=0, ts=TS):
    rng = np.random.default_rng(seed)
    cmd = point_to_point(rng, duration_s=seconds, ts_s=TS)
    cmd = np.vstack([cmd, np.repeat(cmd[-1:], 300, axis=0)])  # end at rest
    out = Plant(PROFILE, seed=seed, effects=effects, nominal=True).simulate(
        Trajectory(ts_s=TS, pos_mm=cmd, e_mm=np.zeros(len(cmd))))
    t = np.arange(len(cmd)) * ts
    write_log(path, t, cmd, out.measured_mm, np.zeros(len(cmd)))
    return cmd, out.measured_mm


def write(path, cmd, meas, ts=TS):
    write_log(path, np.arange(len(cmd)) * ts, cmd, meas, np.zeros(len(cmd)))


def one_line(exc):
    msg = str(exc.value)
    assert "\n" not in msg
    return msg


def test_good_log_reads(tmp_path):
    p = tmp_path / "ok.csv"
    make_log(p)
    log = load_log(p, PROFILE)
    assert log.kind == "encoder" and log.cmd_mm.shape[1] == 3


def test_wrong_machine_ts(tmp_path):
    p = tmp_path / "ts.csv"
    cmd, meas = make_log(tmp_path / "a.csv")
    write(p, cmd, meas, ts=0.001)
    with pytest.raises(LogError) as e:
        load_log(p, PROFILE)
    assert "wrong machine" in one_line(e)


def test_wrong_machine_residual(tmp_path):
    p = tmp_path / "res.csv"
    cmd, meas = make_log(tmp_path / "a.csv")
    meas = meas.copy()
    meas[:, 0] = cmd[0, 0] + 1.5 * (meas[:, 0] - cmd[0, 0])  # another machine's x: 50 % more motion
    write(p, cmd, meas)
    with pytest.raises(LogError) as e:
        load_log(p, PROFILE)
    assert "wrong machine" in one_line(e)


def test_truncated(tmp_path):
    cmd, meas = make_log(tmp_path / "a.csv")
    v = np.abs(np.diff(cmd[:, 0]))
    k = int(np.flatnonzero(v > 0.05)[len(v) // 4 if False else 10]) + 1  # mid-move
    p = tmp_path / "cut.csv"
    write(p, cmd[:max(k, 600)], meas[:max(k, 600)])
    with pytest.raises(LogError) as e:
        load_log(p, PROFILE)
    assert "truncated" in one_line(e)
    p2 = tmp_path / "short.csv"
    write(p2, cmd[:100], meas[:100])
    with pytest.raises(LogError) as e:
        load_log(p2, PROFILE)
    assert "truncated" in one_line(e)


def test_no_motion(tmp_path):
    cmd = np.full((2000, 3), 50.0)
    p = tmp_path / "idle.csv"
    write(p, cmd, cmd + 1e-4)
    with pytest.raises(LogError) as e:
        load_log(p, PROFILE)
    assert "no motion" in one_line(e)


def test_clipped(tmp_path):
    cmd, meas = make_log(tmp_path / "a.csv")
    meas = meas.copy()
    top = np.percentile(meas[:, 0], 80)
    meas[:, 0] = np.minimum(meas[:, 0], top)
    p = tmp_path / "clip.csv"
    write(p, cmd, meas)
    with pytest.raises(LogError) as e:
        load_log(p, PROFILE)
    assert "clipped" in one_line(e)


def test_backlash_is_not_clipping(tmp_path):
    p = tmp_path / "bl.csv"
    make_log(p, effects=[fx.Backlash("x", magnitude_mm=0.15)])
    load_log(p, PROFILE)


def test_observer():
    """Exact model: the observer returns it (the accelerometer agrees). Model blind to a 60 Hz
    motion: the observer recovers it from the acceleration, with the attenuation of its error
    dynamics s²/(s + ω_o)² (0.94 at 60 Hz) and of the bilinear discretisation (measured 0.86)."""
    fs = 500.0
    t = np.arange(5000) / fs
    hf = 0.05 * np.sin(2 * np.pi * 60 * t)
    lf = 10 * np.sin(2 * np.pi * 0.5 * t)
    accel = -(2 * np.pi * 60) ** 2 * hf - (2 * np.pi * 0.5) ** 2 * lf
    est = observer_position(lf + hf, accel, fs)
    # bilinear discretisation at 60 Hz of 500 Hz: measured 4.4 µm peak on a 50 µm sine
    assert np.max(np.abs(est[1000:] - (lf + hf)[1000:])) < 5e-3
    est = observer_position(lf, accel, fs)
    amp = np.std(est[1000:] - lf[1000:]) * np.sqrt(2)
    assert 0.8 * 0.05 < amp < 1.0 * 0.05


def test_diagnose_cli_json(tmp_path):
    p = tmp_path / "pt.csv"
    make_log(p, effects=[fx.PeriodicTime("y", frequency_hz=37.0, amplitude_mm=0.03),
                         fx.SensorNoise("x", std_mm=0.002)], seconds=15.0)
    js, png = tmp_path / "d.json", tmp_path / "d.png"
    r = CliRunner().invoke(cli, ["diagnose", "--machine", "ender3pro", str(p), "--json", str(js),
                                 "--plot", str(png)])
    assert r.exit_code == 0, r.output
    d = json.loads(js.read_text())
    assert set(d["residual_rms_mm"]) == {"x", "y"}
    e = d["effects"][0]
    assert e["kind"] == "periodic_time" and e["axis"] == "y"
    assert abs(e["params"]["frequency_hz"] - 37.0) < 0.74
    assert d["holdout_rms_mm"]["after"]["y"] < 0.5 * d["holdout_rms_mm"]["before"]["y"]
    assert png.stat().st_size > 10_000


def test_diagnose_cli_refuses_in_one_line(tmp_path):
    p = tmp_path / "idle.csv"
    cmd = np.full((2000, 3), 50.0)
    write(p, cmd, cmd)
    r = CliRunner().invoke(cli, ["diagnose", "--machine", "ender3pro", str(p)])
    assert r.exit_code != 0 and "no motion" in r.output


def test_real_klipper_raw_recording(tmp_path):
    """Voron 2.4 belt A: excitation detected and aligned, observer positions on the profile's
    grid; a truncated copy (10 s) is refused in one line."""
    from ..conftest import MEASURED_DIR

    f = MEASURED_DIR / "voron2.4_klipper-raw-accel_belt-test_20231128_221505_A.csv"
    if not f.exists():
        pytest.skip(f"{f} not found")
    log = load_log(f, PROFILE)
    assert log.kind == "klipper_raw" and log.info["generator"] == "legacy"
    assert abs(log.ts_s - PROFILE.ts_s) < 1e-12 and log.cmd_mm.shape[0] > 60_000
    x = log.pos_mm[:, 0]
    assert np.all(np.isfinite(x)) and 0.1 < np.ptp(log.cmd_mm[:, 0]) < 20
    lines = f.read_text().splitlines()
    cut = tmp_path / "cut.csv"
    cut.write_text("\n".join(lines[:4000]) + "\n")
    with pytest.raises(LogError) as e:
        load_log(cut, PROFILE)
    assert "truncated" in one_line(e)
