"""The closed loop with a disturbance the profile lacks (issue 19, point 6): what ``learn``
carries from one print to the next is the *level* of what the twin cannot predict (a fan has a
new phase at every print), and that level reaches the optimizer's chance constraint
(benchmarks/closed_loop.py prints the rounds)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from gcode_feedopt import pipeline
from gcode_feedopt.closedloop import learn as L
from gcode_feedopt.closedloop.logs import load_log
from gcode_feedopt.optimize.methods import make_twin_predictor, plan_schedule, vm_trajectory
from gcode_feedopt.profile import load_profile
from gcode_feedopt.twin.model import axis_noise_mm, learned_noise_mm
from gcode_feedopt.vm import effects as fx
from gcode_feedopt.vm.log import write_log
from gcode_feedopt.vm.metrics import evaluate
from gcode_feedopt.vm.plant import Plant

from ..conftest import REPO
from .test_logs import make_log

P = load_profile("ender3pro")
BUTTERFLY = REPO / "sample_gcode" / "butterfly.gcode"
FAN_MM = 0.02


def fan(phase_rad, axis="x", hz=31.0):
    return fx.PeriodicTime(axis, frequency_hz=hz, amplitude_mm=FAN_MM, phase_rad=phase_rad)


def test_learned_level_is_the_fans_whatever_its_phase(tmp_path):
    """Two logs of the same machine with a 0.02 mm, 31 Hz fan on X at different phases: the
    level learn measures on X is the fan's RMS (0.02/√2 = 14.1 µm) within 10 % on both, and on
    Y (no fan) the encoder's noise, not the profile's σ_ε (10 µm)."""
    levels = []
    for i, phase in enumerate((0.3, 2.9)):
        p = tmp_path / f"l{i}.csv"
        make_log(p, effects=[fan(phase), fx.SensorNoise("x", std_mm=0.001),
                             fx.SensorNoise("y", std_mm=0.001)])
        prof, recs = L.learn_logs(P, [load_log(p, P)])
        rec = {r["axis"]: r for r in recs}
        levels.append(rec["x"]["noise_level_log_mm"])
        assert rec["y"]["noise_level_log_mm"] < 0.003
    np.testing.assert_allclose(levels, FAN_MM / np.sqrt(2), rtol=0.10)


def test_the_learned_level_reaches_the_optimizer_and_survives_the_yaml(tmp_path):
    """After learn, the optimizer's twin uses the learned level per axis (its σ² on X is the
    fan's), and a profile written and read back keeps it (it lives in the record
    ``learned_from`` that the YAML carries); a second log averages with the first in
    variance."""
    from gcode_feedopt.profile.io import save_profile

    p1, p2 = tmp_path / "a.csv", tmp_path / "b.csv"
    make_log(p1, effects=[fan(1.0), fx.SensorNoise("x", std_mm=0.001)])
    make_log(p2, effects=[fx.SensorNoise("x", std_mm=0.001)], seed=1)
    prof, _ = L.learn_logs(P, [load_log(p1, P)])
    lx = learned_noise_mm(prof.twin.priors["x"])
    assert lx == pytest.approx(FAN_MM / np.sqrt(2), rel=0.1)
    tp = make_twin_predictor(prof, "pidd", learn=False)
    np.testing.assert_allclose(tp.s2, [axis_noise_mm(prof, "x") ** 2, axis_noise_mm(prof, "y") ** 2])
    assert tp.s2[0] == pytest.approx(lx ** 2)
    assert make_twin_predictor(P, "pidd", learn=False).s2[0] == pytest.approx(P.twin.sigma_eps_mm ** 2)
    back = load_profile(save_profile(prof, tmp_path / "u.yaml"))
    assert learned_noise_mm(back.twin.priors["x"]) == pytest.approx(lx, rel=1e-6)
    prof2, recs = L.learn_logs(prof, [load_log(p2, prof)])
    new = [r for r in recs if r["axis"] == "x"][0]
    assert learned_noise_mm(prof2.twin.priors["x"]) == pytest.approx(
        np.sqrt(0.5 * (lx ** 2 + new["noise_level_log_mm"] ** 2)), rel=1e-5)


def with_limits(prof, vmax_mm_s, amax_mm_s2):
    lim, fw = prof.limits, prof.firmware
    return dataclasses.replace(
        prof, limits=dataclasses.replace(
            lim, vmax_mm_s=vmax_mm_s, amax_mm_s2=amax_mm_s2,
            axis_amax_mm_s2=dict(lim.axis_amax_mm_s2, x=amax_mm_s2, y=amax_mm_s2)),
        firmware=dataclasses.replace(
            fw, max_accel_mm_s2=dict(fw.max_accel_mm_s2, x=amax_mm_s2, y=amax_mm_s2)))


def closed_loop(prof, tmp_path, *, rounds=3, seed=1, tol=0.06, eta=0.95):
    """(rounds of (cycle s, RMS γ mm, within), conservative cycle s): plan pidd with the
    current profile, run it on the plant (a draw with a fan whose phase is new every print),
    learn from the log as a user would; conservative tuned on the first print's plant."""
    path = pipeline.path_for(pipeline.read_for(BUTTERFLY, prof), prof)
    phases = np.random.default_rng(7).uniform(0, 2 * np.pi, rounds)
    noise = [fx.SensorNoise("x", std_mm=0.001), fx.SensorNoise("y", std_mm=0.001)]
    cons = plan_schedule("conservative", path, prof, tolerance_mm=tol, stringency=eta,
                         plant=Plant(prof, seed=seed, effects=[fan(phases[0]), *noise]))
    out = []
    for k in range(rounds):
        plant = Plant(prof, seed=seed, effects=[fan(phases[k]), *noise])
        sch = plan_schedule("pidd", path, prof, tolerance_mm=tol, stringency=eta)
        tr = vm_trajectory(path, sch.s_mm, sch.ts_s)
        sim = plant.simulate(tr)
        m = evaluate(tr, sim.actual_mm, tol)
        out.append((m.cycle_time_s, m.rms_gamma_mm, m.within_fraction))
        log = tmp_path / f"print{k}.csv"
        write_log(log, tr.t_s, tr.pos_mm, sim.measured_mm, tr.e_mm)
        prof, _ = L.learn_logs(prof, [load_log(log, prof)])
    return out, (cons.s_mm.size - 1) * cons.ts_s


def test_closed_loop_with_a_fan_converges_on_our_simulator(tmp_path):
    """ender3pro draw + a 31 Hz, 0.02 mm fan the profile lacks, butterfly at 150 mm/s, 5 m/s²,
    E_max 0.06 mm, η 0.95: by the third print ≥ η within and RMS γ ≤ (1 − η)·E_max on the
    plant, the cycle no longer than the conservative plan's."""
    eta, tol = 0.95, 0.06
    rounds, cons_s = closed_loop(with_limits(P, 150.0, 5000.0), tmp_path, tol=tol, eta=eta)
    cycle, rms_gamma, within = rounds[2]
    assert within >= eta
    assert rms_gamma <= (1 - eta) * tol
    assert cycle <= cons_s


def test_learn_finds_which_machine_of_the_population_this_is(tmp_path):
    """A plant drawn from the profile's own spread (seed 3) prints one log; learn keeps which
    machine it is (the plant draw's posterior, ``plant_draw``, through the YAML). On another
    trajectory of the same machine (the butterfly at 150 mm/s, 5 m/s²) the learned twin's
    open-loop prediction errs at least 1/0.6 times less than the profile's (measured: x 1.22 →
    0.57 µm, y 3.25 → 0.09 µm RMS), and its interval is narrower (median std 10 → 1 µm: the
    learned level replaces σ_ε)."""
    from gcode_feedopt.closedloop.motion import point_to_point
    from gcode_feedopt.profile.io import save_profile
    from gcode_feedopt.twin.model import axis_twin
    from gcode_feedopt.vm.trajectory import Trajectory

    plant = Plant(P, seed=3, effects=[fx.SensorNoise("x", std_mm=0.001),
                                      fx.SensorNoise("y", std_mm=0.001)])

    def record(seed, path):
        cmd = point_to_point(np.random.default_rng(seed), duration_s=8.0, ts_s=P.ts_s)
        cmd = np.vstack([cmd, np.repeat(cmd[-1:], 300, axis=0)])
        out = plant.simulate(Trajectory(ts_s=P.ts_s, pos_mm=cmd, e_mm=np.zeros(len(cmd))))
        write_log(path, np.arange(len(cmd)) * P.ts_s, cmd, out.measured_mm, np.zeros(len(cmd)))

    record(10, tmp_path / "a.csv")
    prof, recs = L.learn_logs(P, [load_log(tmp_path / "a.csv", P)])
    assert all("plant_draw" in r for r in recs)
    prof = load_profile(save_profile(prof, tmp_path / "u.yaml"))
    fast = with_limits(P, 150.0, 5000.0)
    path = pipeline.path_for(pipeline.read_for(BUTTERFLY, fast), fast)
    sch = plan_schedule("kinematic", path, fast, tolerance_mm=0.1, stringency=0.95)
    tr = vm_trajectory(path, sch.s_mm, sch.ts_s)
    cmd, actual = tr.pos_mm, plant.run(tr)
    for i, ax in enumerate("xy"):
        m0, s0 = axis_twin(P, ax).run(cmd[:, i], None, learn=False)
        m1, s1 = axis_twin(prof, ax).run(cmd[:, i], None, learn=False)
        e0 = np.sqrt(np.mean((m0 - actual[:, i]) ** 2))
        e1 = np.sqrt(np.mean((m1 - actual[:, i]) ** 2))
        assert e1 < 0.6 * e0, (ax, e0, e1)
        assert np.median(s1) < np.median(s0)


def test_a_fan_written_by_diagnose_is_counted_once(tmp_path):
    """A fan ``diagnose -o`` wrote as an extension (periodic_time: variance A²/2, no phase)
    widens the optimizer's constraint by A²/2; learning a log of that fan then measures only
    what is left (the encoder's noise), so the fan is not counted twice."""
    ext = {"kind": "periodic_time", "params": {"frequency_hz": 31.0, "amplitude_mm": FAN_MM}}
    axes = dict(P.axes, x=dataclasses.replace(P.axes["x"], effects=(ext,)))
    prof = dataclasses.replace(P, axes=axes)
    tp = make_twin_predictor(prof, "pidd", learn=False)
    assert tp.s2[0] == pytest.approx(P.twin.sigma_eps_mm ** 2 + FAN_MM ** 2 / 2)
    assert tp.s2[1] == pytest.approx(P.twin.sigma_eps_mm ** 2)
    p = tmp_path / "fan.csv"
    make_log(p, effects=[fan(0.7), fx.SensorNoise("x", std_mm=0.001)])
    learned, recs = L.learn_logs(prof, [load_log(p, prof)])
    assert [r for r in recs if r["axis"] == "x"][0]["noise_level_log_mm"] < 0.004
    tp = make_twin_predictor(learned, "pidd", learn=False)
    assert tp.s2[0] == pytest.approx(axis_noise_mm(learned, "x") ** 2 + FAN_MM ** 2 / 2)


def test_an_unmodelled_lag_is_learned_as_speed_dependent_and_the_loop_keeps_the_tolerance(tmp_path):
    """A hidden 3 ms X delay (ender3pro draw seed 2, 300 butterfly lines, E_max 0.1 mm, η 0.95):
    its error ≈ delay·v vanishes at rest, so learn puts it in the speed term (k_v ≈ 3 ms, a
    level at rest of a few µm), not in a constant the optimizer could never slow down for (as
    a constant it would exceed the tolerance at rest: 0.24 mm at z·σ). The first print breaks
    the tolerance (within 0.83); the second, planned with what learn wrote, keeps it. (The log,
    1,790 samples, is too short for a residual filter, twin.residual: none is fitted.)"""
    prof = P
    lines = BUTTERFLY.read_bytes().splitlines(keepends=True)[:300]
    piece = tmp_path / "piece.gcode"
    piece.write_bytes(b"".join(lines))
    path = pipeline.path_for(pipeline.read_for(piece, prof), prof)
    plant = Plant(prof, seed=2, effects=[fx.Delay("x", delay_s=0.003),
                                         fx.SensorNoise("x", std_mm=0.001),
                                         fx.SensorNoise("y", std_mm=0.001)])
    within = []
    for k in range(2):
        sch = plan_schedule("pidd", path, prof, tolerance_mm=0.1, stringency=0.95)
        tr = vm_trajectory(path, sch.s_mm, sch.ts_s)
        sim = plant.simulate(tr)
        within.append(evaluate(tr, sim.actual_mm, 0.1).within_fraction)
        log = tmp_path / f"p{k}.csv"
        write_log(log, tr.t_s, tr.pos_mm, sim.measured_mm, tr.e_mm)
        prof, recs = L.learn_logs(prof, [load_log(log, prof)])
        if k == 0:
            rx = [r for r in recs if r["axis"] == "x"][0]
            assert 0.0015 < rx["noise_per_speed_log_s"] < 0.004
            assert rx["noise_level_log_mm"] < 0.01
            assert rx["residual_filter_log_rms_mm"] == 0.0
    assert within[0] < 0.95 <= within[1]


def _bare_twin_and_command(tmp_path):
    """ender3pro's x twin without its known uncertainty (no plant draw to explain anything),
    a butterfly log's x command and the twin's open-loop mean on it."""
    from gcode_feedopt.twin.frf import ImpulseResponse
    from gcode_feedopt.twin.model import axis_twin

    p = tmp_path / "l.csv"
    make_log(p)
    x = np.loadtxt(p, delimiter=",", skiprows=1)[:, 1]
    tw = axis_twin(P, "x")
    ir = tw.ir
    bare = dataclasses.replace(tw, ir=ImpulseResponse(
        ts_s=ir.ts_s, mean=ir.mean, var=np.zeros_like(ir.var), factor=np.zeros((ir.mean.size, 0))))
    mean, _ = dataclasses.replace(bare).run(x, None, learn=False)
    return tw, bare, x, mean


def _carried(tw, x, mean, terms):
    """The standard deviation the twin's interval carries, sample by sample, for
    ``unexplained_level``'s terms (σ_r, k_v, ρ, g)."""
    from gcode_feedopt.twin.residual import filter_series

    lv, kv, rho, g = terms
    v = np.gradient(x) / tw.ir.ts_s
    f = filter_series(g[:, None], x - x[0])[0]
    return np.sqrt(f * f + lv ** 2 + kv ** 2 * v * v + rho ** 2 * (mean - x) ** 2)


def test_the_unexplained_level_carries_what_is_linear_in_the_motion_sample_by_sample(tmp_path):
    """Closed forms: a residual 0.1 × the twin's predicted dynamic error, 3 ms × the commanded
    speed, or 20 ms × the commanded speed seen through a 50 ms first-order lag (a servo's slow
    pole: neither v nor d has that shape) are each a filter of the command, and the interval
    carries each sample by sample (RMS of the difference ≤ 5 % of the residual's; measured
    0.33 %, 0.011 %, 0.0004 %), not as a level; a 10 µm fan is not one: no filter is kept
    (twin.residual.MIN_EXPLAINED) and it is a level of 10/√2 µm (measured −0.02 %)."""
    from scipy.signal import lfilter

    _, bare, x, mean = _bare_twin_and_command(tmp_path)
    v = np.gradient(x) / bare.ir.ts_s
    t = np.arange(x.size) * bare.ir.ts_s
    a = np.exp(-bare.ir.ts_s / 0.05)

    def rms(q):
        return np.sqrt(np.mean(q * q))

    for r in (0.1 * (mean - x), 0.003 * v, lfilter([1 - a], [1, -a], 0.02 * v)):
        terms = L.unexplained_level(bare, x, mean + r)
        assert rms(_carried(bare, x, mean, terms) - np.abs(r)) <= 0.05 * rms(r)
        assert terms[0] <= 0.05 * rms(r)
    fan = 0.01 * np.sin(2 * np.pi * 31.0 * t)
    terms = L.unexplained_level(bare, x, mean + fan)
    assert not np.any(terms[3])
    assert terms[0] == pytest.approx(0.01 / np.sqrt(2), rel=0.01)


def test_a_residual_beyond_the_spread_the_twin_carries_is_counted(tmp_path):
    """What the profile's spread explains is not counted (the twin's interval carries it): a
    residual that is one standard draw along the spread's main direction leaves nothing. Ten
    such draws are beyond what the interval carries (χ² of its directions at 99 %: 4.65 for
    ender3pro's 9): the part beyond it is counted, RMS (10 − 4.65)/10 of the residual."""
    from scipy.stats import chi2

    from gcode_feedopt.twin.features import factor_series

    tw, _, x, _ = _bare_twin_and_command(tmp_path)
    mean, _ = dataclasses.replace(tw).run(x, None, learn=False)
    Y = factor_series(tw.ir, x - x[0])
    u = np.linalg.svd(Y, full_matrices=False)[0][:, 0]
    for k in (1.0, 10.0):
        r = k * (u @ Y)
        carried = _carried(tw, x, mean, L.unexplained_level(tw, x, mean + r))
        modelled = np.sqrt(np.mean(carried ** 2))
        rms = np.sqrt(np.mean(r * r))
        if k == 1.0:
            assert modelled < 0.01 * rms
        else:
            beyond = (k - np.sqrt(chi2.ppf(L.SPREAD_QUANTILE, Y.shape[0]))) / k
            assert modelled == pytest.approx(beyond * rms, rel=0.1)


@pytest.mark.shared_data
def test_closed_loop_with_a_fan_converges_on_a_benchA_plant(bench_a, tmp_path):
    """The same loop on a profile built from benchA's FRFs (a machine simulated apart from this
    project; modes 47/37 Hz) with a draw of it as the plant: by the third print within ≥ η,
    RMS γ ≤ (1 − η)·E_max and the cycle no longer than the conservative plan's (measured:
    8.15 s against 8.80)."""
    eta, tol = 0.95, 0.06
    rounds, cons_s = closed_loop(with_limits(bench_a[0], 150.0, 5000.0), tmp_path, tol=tol,
                                 eta=eta)
    cycle, rms_gamma, within = rounds[2]
    assert within >= eta
    assert rms_gamma <= (1 - eta) * tol
    assert cycle <= cons_s
