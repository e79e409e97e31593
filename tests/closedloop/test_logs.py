"""Log reading and refusal of bad logs; the observer; diagnose CLI end to end."""

import json
import re

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


def test_other_sample_periods_are_resampled(tmp_path):
    """A 1 ms logger (here: the 2 ms log with its midpoints) comes back to the 2 ms grid
    sample for sample; a 4 ms one (every other sample) by linear interpolation. Both warn."""
    from gcode_feedopt.errors import LogWarning

    cmd, meas = make_log(tmp_path / "a.csv", effects=[fx.SensorNoise("x", std_mm=0.001)])
    fine_c = np.empty((2 * len(cmd) - 1, cmd.shape[1]))
    fine_m = np.empty_like(fine_c)
    fine_c[0::2], fine_c[1::2] = cmd, 0.5 * (cmd[:-1] + cmd[1:])
    fine_m[0::2], fine_m[1::2] = meas, 0.5 * (meas[:-1] + meas[1:])
    p = tmp_path / "1ms.csv"
    write(p, fine_c, fine_m, ts=0.001)
    with pytest.warns(LogWarning, match="sampled every 1 ms.*one sample in 2 kept"):
        log = load_log(p, PROFILE)
    assert log.ts_s == TS
    np.testing.assert_allclose(log.cmd_mm[:, :2], cmd[:, :2], atol=1e-6)
    np.testing.assert_allclose(log.pos_mm[:, :2], meas[:, :2], atol=1e-6)
    p = tmp_path / "4ms.csv"
    write(p, cmd[::2], meas[::2], ts=0.004)
    with pytest.warns(LogWarning, match="sampled every 4 ms.*linear interpolation"):
        log = load_log(p, PROFILE)
    assert log.ts_s == TS and abs(log.cmd_mm.shape[0] - len(cmd)) <= 1
    np.testing.assert_allclose(log.cmd_mm[::2, :2], cmd[::2][:log.cmd_mm[::2].shape[0], :2],
                               atol=1e-6)


@pytest.mark.parametrize("name, truth", [("log_01.csv", None), ("log_04.csv", ("delay", "y")),
                                         ("log_06.csv", ("periodic_position", "x"))])
@pytest.mark.parametrize("step", [2, "mid"])
def test_bench_a_logs_at_other_periods(tmp_path, name, truth, step):
    """benchA's logs at 4 ms (every other sample) and 1 ms (midpoints inserted) against the
    profile built from its FRFs (2 ms): the diagnosis names what the 2 ms log names."""
    import warnings

    from gcode_feedopt.closedloop.diagnose import diagnose_log
    from gcode_feedopt.profile.build import build_from_frfs

    from ..conftest import REPO

    bench = REPO.parent / "shared" / "data" / "independent"
    if not bench.is_dir():
        pytest.skip("no benchA")
    prof, _ = build_from_frfs(PROFILE, {a: sorted((bench / "frf").glob(f"{a}_*.csv"))
                                        for a in "xy"}, name="benchA")
    d = np.loadtxt(bench / "logs" / name, delimiter=",", skiprows=1)
    if step == 2:
        d = d[::2]
    else:
        fine = np.empty((2 * len(d) - 1, d.shape[1]))
        fine[0::2], fine[1::2] = d, 0.5 * (d[:-1] + d[1:])
        d = fine
    p = tmp_path / name
    np.savetxt(p, d, delimiter=",", header="t,x_cmd,y_cmd,x,y", comments="", fmt="%.7f")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        top = diagnose_log(load_log(p, prof), prof).effects[0]
    if truth is None:
        assert top["kind"] == "none", top
    else:
        assert (top["kind"], top["axis"]) == truth, top


@pytest.mark.parametrize("scale, said", [
    (1e3, r"t steps by 2 per row: is t in milliseconds\?.*divide the column by 1000"),
    (1e6, r"t steps by 2000 per row: is t in microseconds\?.*divide the column by 1e\+06"),
    (100.0, r"t steps by 0\.2 per row: is t in milliseconds\?.*in seconds, the log is too "
            r"coarse to show a printer's motion"),
])
def test_a_time_column_not_in_seconds_is_refused(tmp_path, scale, said):
    """A 2 ms log whose t is in ms or µs steps by 2 or 2000 "s" per row; resampled to Ts it
    became 10⁶ rows of interpolated nonsense and ran for minutes. `learn` / `diagnose`
    (load_log) and `predict` refuse it in one line naming the unit; a log truly sampled
    every 0.2 s (or t in ms of a 5 kHz logger) is refused saying both. The file is
    untouched."""
    cmd, meas = make_log(tmp_path / "a.csv", seconds=2.0)
    p = tmp_path / "t.csv"
    write(p, cmd, meas, ts=TS * scale)
    before = p.read_bytes()
    with pytest.raises(LogError, match=said) as e:
        load_log(p, PROFILE)
    one_line(e)
    res = CliRunner().invoke(cli, ["predict", "--machine", "ender3pro", str(p), "-o",
                                   str(tmp_path / "p.csv")])
    assert res.exit_code == 2 and re.search(said, res.output), res.output
    assert p.read_bytes() == before and not (tmp_path / "p.csv").exists()


def test_wrong_machine_residual(tmp_path):
    p = tmp_path / "res.csv"
    cmd, meas = make_log(tmp_path / "a.csv")
    meas = meas.copy()
    meas[:, 0] = cmd[0, 0] + 1.5 * (meas[:, 0] - cmd[0, 0])  # another machine's x: 50 % more motion
    write(p, cmd, meas)
    with pytest.raises(LogError) as e:
        load_log(p, PROFILE)
    assert "wrong machine" in one_line(e)


def cut_mid_move(cmd, meas, start_frac, end_frac):
    """The rows of a log between two samples taken while the command moves fast."""
    v = np.linalg.norm(np.diff(cmd[:, :2], axis=0), axis=1) / TS
    fast = np.flatnonzero(v > 20.0)
    i0 = int(fast[int(start_frac * (fast.size - 1))]) + 1
    i1 = int(fast[int(end_frac * (fast.size - 1))]) + 1
    return i0, i1


def test_log_cut_mid_motion_is_used(tmp_path):
    """A log cut at both ends while the command moves (as a user's logger gives it): used, one
    warning per cut edge; the warm-up is the twin's memory (n_taps + max(n2, n3)); from there
    on the physics' prediction is the one the whole log gives (the twin is causal)."""
    from gcode_feedopt.twin.physics import nominal_impulse
    from gcode_feedopt.closedloop.logs import twin_memory
    from gcode_feedopt.errors import LogWarning
    from gcode_feedopt.vm.plant import respond

    cmd, meas = make_log(tmp_path / "a.csv", effects=[fx.SensorNoise("x", std_mm=0.001)])
    i0, i1 = cut_mid_move(cmd, meas, 0.2, 0.8)
    p = tmp_path / "cut.csv"
    write(p, cmd[i0:i1], meas[i0:i1])
    with pytest.warns(LogWarning) as rec:
        log = load_log(p, PROFILE)
    msgs = [str(w.message) for w in rec]
    assert len(msgs) == 2 and all("\n" not in m for m in msgs)
    assert "starts mid-motion" in msgs[0] and "530 samples (1.06 s" in msgs[0]
    assert "ends mid-motion" in msgs[1]
    W = twin_memory(PROFILE)
    assert log.warmup == W == PROFILE.twin.n_taps + max(PROFILE.twin.n2, PROFILE.twin.n3)
    h = nominal_impulse(PROFILE)["x"][0]
    full, cut = respond(cmd[:, 0], h), respond(cmd[i0:i1, 0], h)
    n = PROFILE.twin.n_taps
    np.testing.assert_allclose(cut[n - 1:], full[i0 + n - 1:i1], atol=1e-9)
    assert np.max(np.abs(cut[:n // 10] - full[i0:i0 + n // 10])) > 1e-3  # the warm-up is not
    # ends mid-motion only: no warm-up, one warning
    p2 = tmp_path / "end.csv"
    write(p2, cmd[:i1], meas[:i1])
    with pytest.warns(LogWarning, match="ends mid-motion") as rec:
        assert load_log(p2, PROFILE).warmup == 0
    assert len(rec) == 1


def test_edge_speeds_at_rest_and_moving():
    """A command starting from rest at its first sample or stopping within its last one is at
    rest there (the optimizer's plans end at 1-2 mm/s on the last step); cut while moving, it
    keeps its speed."""
    from gcode_feedopt.closedloop.logs import edge_speeds_mm_s

    t = np.arange(0, 1.0 + TS / 2, TS)
    a = 1500.0
    s = np.where(t < 0.5, 0.5 * a * t ** 2, 0.5 * a * 0.25 - 0.5 * a * (1.0 - t) ** 2 + 0.5 * a * 0.25)
    s = s - s[0]
    cmd = np.column_stack([s, 0.5 * s, 0 * s])
    v_last = np.linalg.norm(cmd[-1, :2] - cmd[-2, :2]) / TS
    assert 1.0 < v_last < 2.0  # the last step of a stop sampled at Ts
    assert edge_speeds_mm_s(cmd, TS) == (0.0, 0.0)
    v0, v1 = edge_speeds_mm_s(cmd[100:400], TS)
    assert v0 == pytest.approx(np.linalg.norm(cmd[101, :2] - cmd[100, :2]) / TS)
    assert v1 == pytest.approx(np.linalg.norm(cmd[399, :2] - cmd[398, :2]) / TS)
    assert edge_speeds_mm_s(np.full((10, 3), 5.0), TS) == (0.0, 0.0)


def test_too_short_refused(tmp_path):
    """Fewer samples than the twin has weights (after the warm-up) identify nothing: refused in
    one line saying how many are needed; a short motion that is long enough is used with a
    warning."""
    from gcode_feedopt.errors import LogWarning

    cmd, meas = make_log(tmp_path / "a.csv")
    p = tmp_path / "short.csv"
    write(p, cmd[:30], meas[:30])
    with pytest.raises(LogError) as e:
        load_log(p, PROFILE)
    assert "too short" in one_line(e) and "42 weights" in one_line(e)
    r = CliRunner().invoke(cli, ["diagnose", "--machine", "ender3pro", str(p)])
    assert r.exit_code == 2 and "too short" in r.output and r.output.count("\n") == 1
    i0, _ = cut_mid_move(cmd, meas, 0.3, 0.3)
    p2 = tmp_path / "short_mid.csv"
    write(p2, cmd[i0:i0 + 560], meas[i0:i0 + 560])
    with pytest.raises(LogError) as e:
        load_log(p2, PROFILE)
    msg = one_line(e)
    assert "too short" in msg and "warm-up" in msg and "log at least 572 samples" in msg
    p3 = tmp_path / "brief.csv"
    write(p3, cmd[:200], meas[:200])
    with pytest.warns(LogWarning, match="short motion"):
        load_log(p3, PROFILE)


def test_motion_only_in_the_warmup_is_no_motion(tmp_path):
    """A log that starts mid-motion and stops within its warm-up has nothing usable."""
    t = np.arange(1500) * TS
    x = 50.0 + np.minimum(t, 0.2) * 40.0  # moving at 40 mm/s at t=0, at rest from 0.2 s
    cmd = np.column_stack([x, np.full_like(x, 80.0), 0 * x])
    p = tmp_path / "w.csv"
    write(p, cmd, cmd)
    with pytest.raises(LogError) as e:
        load_log(p, PROFILE)
    assert "no motion" in one_line(e) and "warm-up" in one_line(e)


def test_planned_trajectory_is_not_a_machine_log(tmp_path):
    """`optimize --trajectory` writes t,x,y,z,e (commands only): learn/diagnose refuse it in one
    line naming it, `predict` reads it (its x, y as the commands)."""
    from ..conftest import REPO

    traj = tmp_path / "plan.csv"
    out = tmp_path / "o.gcode"
    gc = tmp_path / "in.gcode"
    lines = (REPO / "sample_gcode" / "butterfly.gcode").read_bytes().splitlines(keepends=True)
    gc.write_bytes(b"".join(lines[:200]))
    r = CliRunner().invoke(cli, ["optimize", str(gc), "-o", str(out), "--machine", "ender3pro",
                                 "--trajectory", str(traj), "--quiet"])
    assert r.exit_code == 0, r.output
    assert traj.read_text().splitlines()[0] == "t,x,y,z,e"
    with pytest.raises(LogError) as e:
        load_log(traj, PROFILE)
    assert "planned trajectory" in one_line(e)
    r = CliRunner().invoke(cli, ["learn", "-m", "ender3pro", str(traj), "-o", str(tmp_path / "u.yaml")])
    assert r.exit_code == 2 and "planned trajectory" in r.output
    pred = tmp_path / "pred.csv"
    r = CliRunner().invoke(cli, ["predict", "-m", "ender3pro", str(traj), "-o", str(pred)])
    assert r.exit_code == 0, r.output
    plan = np.loadtxt(traj, delimiter=",", skiprows=1)
    got = np.loadtxt(pred, delimiter=",", skiprows=1)
    assert got.shape[0] == plan.shape[0]
    assert np.max(np.abs(got[:, 1] - plan[:, 1])) < 0.5  # the prediction follows the plan


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
    # a fan keeps no phase from print to print: the written profile carries it as variance,
    # so only this log's fit (its phase) lowers the held-out error
    assert d["holdout_rms_mm"]["after_fitted"]["y"] < 0.5 * d["holdout_rms_mm"]["before"]["y"]
    assert d["holdout_rms_mm"]["after"]["y"] == d["holdout_rms_mm"]["before"]["y"]
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


# --- benchA (../shared/data/independent): logs cut as users have them -------------------------


def _twin_fit(prof, cmd, meas, warmup=0):
    """Per axis (RMS of measured - predicted, coverage of the 95 % interval) over samples from
    ``warmup`` on, and the predicted means, of the twin learning online."""
    from gcode_feedopt.twin.model import axis_twin

    out, means = [], []
    for i, ax in enumerate("xy"):
        m, s = axis_twin(prof, ax).run(cmd[:, i], meas[:, i], warmup=warmup)
        r = meas[:, i] - m
        out.append((float(np.sqrt(np.mean(r ** 2))), float(np.mean(np.abs(r) <= 1.959964 * s))))
        means.append(m)
    return out, np.column_stack(means)


def test_bench_a_log_13_ends_mid_motion(bench_a):
    """log_13 = benchA's log_01 cut at 60 % (ends at 41.6 mm/s): used with one warning, no
    warm-up; the twin's prediction on it matches log_01's on the same samples (RMS 0.63/0.64 µm,
    coverage 96.0/95.6 % vs 96.0/96.6 %: only the noise level, estimated from each log, differs)."""
    from gcode_feedopt.errors import LogWarning

    from ..conftest import INDEPENDENT_DIR, bench_a_log

    prof, labels = bench_a
    assert any(e["file"] == "logs/log_13.csv" and e["truncation"]["kind"] == "cut_end"
               for e in labels["logs"] if "truncation" in e)
    with pytest.warns(LogWarning, match="ends mid-motion") as rec:
        log = load_log(INDEPENDENT_DIR / "logs" / "log_13.csv", prof)
    assert len(rec) == 1 and log.warmup == 0
    c13, m13 = bench_a_log("log_13.csv")
    c01, m01 = bench_a_log("log_01.csv")
    K = c13.shape[0]
    np.testing.assert_array_equal(c13, c01[:K])
    f13, _ = _twin_fit(prof, c13, m13)
    f01, _ = _twin_fit(prof, c01[:K], m01[:K])  # same samples, the log_01 twin run to K only
    for (r13, cov13), (r01, cov01) in zip(f13, f01):
        assert r13 == pytest.approx(r01, rel=0.05) and r13 < 1e-3
        assert abs(cov13 - cov01) < 0.02 and 0.93 <= cov13 <= 0.97


def test_bench_a_log_14_starts_mid_print(bench_a):
    """log_14 = benchA's log_03 with its first 30 % dropped (starts at 61 mm/s): used with one
    warning and a warm-up of the twin's memory (530 samples); after it, the twin learning online
    gives what it gives on log_03 learning from the same sample on (means within 10 nm,
    measured 1.6 nm), RMS 0.61/0.62 µm and coverage 95 %."""
    from gcode_feedopt.closedloop.logs import twin_memory
    from gcode_feedopt.errors import LogWarning

    from ..conftest import INDEPENDENT_DIR, bench_a_log

    prof, _ = bench_a
    with pytest.warns(LogWarning, match="starts mid-motion") as rec:
        log = load_log(INDEPENDENT_DIR / "logs" / "log_14.csv", prof)
    assert len(rec) == 1
    W = twin_memory(prof)
    assert log.warmup == W == 530
    c14, m14 = bench_a_log("log_14.csv")
    c03, m03 = bench_a_log("log_03.csv")
    off = c03.shape[0] - c14.shape[0]
    np.testing.assert_array_equal(c14, c03[off:])
    f14, p14 = _twin_fit(prof, c14, m14, warmup=W)
    _, p03 = _twin_fit(prof, c03, m03, warmup=off + W)
    np.testing.assert_allclose(p14[W:], p03[off + W:], atol=1e-5)
    for i in range(2):
        r = m14[W:, i] - p14[W:, i]
        assert np.sqrt(np.mean(r ** 2)) < 1e-3
    # without the warm-up left out the first second would be scored: its error is the unknown past
    early = np.sqrt(np.mean((m14[:W // 2, 1] - p14[:W // 2, 1]) ** 2))
    late = np.sqrt(np.mean((m14[W:, 1] - p14[W:, 1]) ** 2))
    assert early > 3 * late


def test_bench_a_cut_logs_through_the_cli(bench_a, tmp_path):
    """predict, learn and diagnose take log_13 and log_14 with the profile built from benchA's
    FRFs: exit 0, one warning each; predict's summary leaves log_14's warm-up out; learn
    records it."""
    import yaml

    from gcode_feedopt.errors import LogWarning
    from gcode_feedopt.profile.io import save_profile

    from ..conftest import INDEPENDENT_DIR

    prof, _ = bench_a
    yml = save_profile(prof, tmp_path / "benchA.yaml")
    logs = INDEPENDENT_DIR / "logs"
    for name, what in (("log_13.csv", "ends mid-motion"), ("log_14.csv", "starts mid-motion")):
        f = str(logs / name)
        for args in (["predict", "-m", str(yml), f, "-o", str(tmp_path / "p.csv")],
                     ["learn", "-m", str(yml), f, "-o", str(tmp_path / "u.yaml")],
                     ["diagnose", "-m", str(yml), f, "--json", str(tmp_path / "d.json")]):
            if args[0] == "predict" and what == "ends mid-motion":
                r = CliRunner().invoke(cli, args)  # a cut end changes nothing for predict
            else:
                with pytest.warns(LogWarning, match=what):
                    r = CliRunner().invoke(cli, args)
            assert r.exit_code == 0, (name, args[0], r.output)
            if args[0] == "predict":
                assert ("samples 530-3680" in r.output) == (name == "log_14.csv"), r.output
        rec = yaml.safe_load((tmp_path / "u.yaml").read_text())["twin"]["priors"]["y"]["learned_from"][-1]
        assert rec["warmup_samples"] == (530 if name == "log_14.csv" else 0)
        d = json.loads((tmp_path / "d.json").read_text())
        assert set(d["residual_rms_mm"]) == {"x", "y"}
        assert d["log"]["warmup_samples"] == (530 if name == "log_14.csv" else 0)


@pytest.mark.parametrize("clock", ["values at the stamps", "stamps of uniform samples"])
def test_bench_a_log_with_jittered_times_is_diagnosed_as_written(bench_a, tmp_path, clock):
    """benchA's log_07 (a 17.5 Hz, 15 µm fan on y) as a host-polled logger writes it: ±0.4 ms
    of jitter on its 2 ms, 20 samples dropped; the values either taken at those times (a
    cubic spline through the log) or left on the grid with late/early stamps. Read on the
    grid (one warning saying which clock it trusted), it is diagnosed as the log itself: the
    fan on y, frequency and amplitude within 5 % of the labels. Read in the other clock
    (interpolated at its stamps), the stamps' version errs by 24 µm RMS on x (checked by
    hand: `diagnose` then finds nothing)."""
    import warnings

    from scipy.interpolate import CubicSpline

    from gcode_feedopt.closedloop.diagnose import diagnose_log
    from gcode_feedopt.errors import LogWarning

    from ..conftest import INDEPENDENT_DIR

    prof, labels = bench_a
    truth = next(e for e in labels["logs"] if e["file"] == "logs/log_07.csv")["effects"][0]
    a = np.loadtxt(INDEPENDENT_DIR / "logs" / "log_07.csv", delimiter=",", skiprows=1)
    rng = np.random.default_rng(0)
    t = a[:, 0] + np.r_[0, rng.uniform(-4e-4, 4e-4, len(a) - 2), 0]
    keep = np.ones(len(a), bool)
    keep[rng.choice(np.arange(5, len(a) - 5), 20, replace=False)] = False
    if clock == "values at the stamps":
        rows = np.column_stack([t] + [CubicSpline(a[:, 0], a[:, k])(t) for k in range(1, 5)])
        said = "every column interpolated on that grid at the logged times"
    else:
        rows = np.column_stack([t, a[:, 1:]])
        said = "the rows taken as that grid's samples"
    p = tmp_path / "log_07_jitter.csv"
    np.savetxt(p, rows[keep], delimiter=",", header="t,x_cmd,y_cmd,x,y", comments="",
               fmt="%.6f")
    with pytest.warns(LogWarning, match=f"20 sample.s. missing.: {said}"):
        log = load_log(p, prof)
    assert log.ts_s == prof.ts_s and log.cmd_mm.shape[0] == len(a)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        top = diagnose_log(log, prof).effects[0]
    assert (top["kind"], top["axis"]) == (truth["kind"], truth["axis"]), top
    for k in ("frequency_hz", "amplitude_mm"):
        assert top["params"][k] == pytest.approx(truth["params"][k], rel=0.05), top
