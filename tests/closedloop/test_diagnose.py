"""Hide an effect in a virtual-machine log; diagnose must name it (issues 6 and 19).

The plant is the twin's mean response (``nominal=True``) plus 1 µm sensor noise (an
encoder-class sensor) plus one seeded random effect (``vm.effects.random_effect``). Fast run:
3 seeds per kind; ≥ 20 seeds per kind run under ``-m slow``. Clean logs of plants *drawn* from
the profile's spread (the machine is not the twin's mean) must give ``none``: the diagnosis
absorbs what the known uncertainty allows before it names anything. benchA (a machine
simulated elsewhere) is in test_diagnose_bench_a.py.
"""

import numpy as np
import pytest

from gcode_feedopt.closedloop.catalogue import _walk, sincos_rss, undo_response
from gcode_feedopt.closedloop.diagnose import KINDS, diagnose_arrays, leftover
from gcode_feedopt.twin.physics import axis_physics
from gcode_feedopt.closedloop.motion import point_to_point
from gcode_feedopt.profile import load_profile
from gcode_feedopt.vm import effects as fx
from gcode_feedopt.vm.plant import Plant
from gcode_feedopt.vm.trajectory import Trajectory

PROFILE = load_profile("ender3pro")
IMPULSE = axis_physics(PROFILE)
MODE_HZ = fx.dominant_mode_hz(IMPULSE["x"].mean, PROFILE.ts_s)
NOISE_MM = 0.001
SCALE_PARAM = {"periodic_time": "frequency_hz", "periodic_position": "wavelength_mm",
               "resonance_shift": "frequency_hz"}


def run_case(kind, seed, nominal=True):
    rng = np.random.default_rng(1000 + seed)
    cmd = point_to_point(rng, duration_s=20.0, ts_s=PROFILE.ts_s)
    hidden = None if kind == "none" else fx.random_effect(rng, kind, mode_hz=MODE_HZ)
    eff = ([hidden] if hidden else []) + [fx.SensorNoise("x", std_mm=NOISE_MM),
                                          fx.SensorNoise("y", std_mm=NOISE_MM)]
    out = Plant(PROFILE, seed=seed, effects=eff, nominal=nominal).simulate(
        Trajectory(ts_s=PROFILE.ts_s, pos_mm=cmd, e_mm=np.zeros(len(cmd))))
    return hidden, diagnose_arrays(cmd, out.measured_mm, PROFILE.ts_s, IMPULSE)


def check(kind, seeds):
    right = 0
    for seed in seeds:
        hidden, d = run_case(kind, seed)
        top = d.effects[0]
        if kind == "none":
            right += top["kind"] == "none"
            continue
        ok = top["kind"] == kind and top["axis"] == hidden.axis
        if ok and kind in SCALE_PARAM:
            key = SCALE_PARAM[kind]
            true = hidden.params()[key]
            ok = abs(top["params"][key] - true) <= 0.02 * true
        ax = hidden.axis
        # the held-out error at least halves, or reaches the sensor's noise (a 1.8 µm shift
        # in 1 µm noise cannot halve)
        ok = ok and d.holdout_rms_mm["after"][ax] <= max(0.5 * d.holdout_rms_mm["before"][ax],
                                                         1.1 * NOISE_MM)
        right += ok
    return right / len(seeds)


@pytest.mark.parametrize("kind", [*KINDS, "none"])
def test_hidden_effect_found_fast(kind):
    assert check(kind, range(3)) == 1.0


@pytest.mark.slow
@pytest.mark.parametrize("kind", [*KINDS, "none"])
def test_hidden_effect_found_20_seeds(kind):
    assert check(kind, range(100, 120)) >= 0.95


@pytest.mark.parametrize("seed", range(10))
def test_clean_drawn_plants_name_nothing(seed):
    """Ten machines drawn from the profile's spread (not its mean), no effect: none. The
    twin's mean misses them by up to several µm; the plant draw absorbs that to the noise."""
    _, d = run_case("none", 200 + seed, nominal=False)
    assert [e["kind"] for e in d.effects] == ["none"], d.effects
    assert max(d.holdout_rms_mm["plant_draw_only"].values()) < 1.3 * NOISE_MM


def test_json_keys():
    hidden, d = run_case("periodic_time", 7)
    j = d.to_dict()
    assert set(j["residual_rms_mm"]) == {"x", "y"}
    assert set(j["holdout_rms_mm"]) >= {"before", "after", "plant_draw_only"}
    e = j["effects"][0]
    assert set(e) >= {"kind", "axis", "params", "confidence"}
    assert e["kind"] == "periodic_time" and 0 <= e["confidence"] <= 1
    # ranked by the sum of squares explained on the fit part; the test's figures reported
    ss = [c.explained_fit for c in d.candidates]
    assert ss == sorted(ss, reverse=True)
    assert e["test"]["t_holdout"] > e["test"]["crit_holdout"]


@pytest.mark.parametrize("delay_s", [0.003, 0.008])
def test_delay_on_steady_motion_is_a_delay(delay_s):
    """The first 300 lines of the butterfly on the kinematic plan: the fit part is mostly
    steady motion on X, where a delay, a friction and a backlash are the same constant lag
    (the fit part cannot tell them apart); the held-out part can, and names the delay.
    (An 8 ms delay was named backlash 0.31 mm here, held-out RMS 457 → 134 µm.)"""
    import pathlib
    import tempfile

    from gcode_feedopt.optimize.methods import plan_schedule, vm_trajectory
    from gcode_feedopt.pipeline import path_for, read_for

    repo = pathlib.Path(__file__).resolve().parents[2]
    lines = (repo / "sample_gcode" / "butterfly.gcode").read_bytes().splitlines(keepends=True)
    with tempfile.TemporaryDirectory() as tmp:
        piece = pathlib.Path(tmp) / "piece.gcode"
        piece.write_bytes(b"".join(lines[:300]))
        path = path_for(read_for(piece, PROFILE), PROFILE)
    sched = plan_schedule("kinematic", path, PROFILE, tolerance_mm=0.1, stringency=0.95)
    tr = vm_trajectory(path, sched.s_mm, sched.ts_s)
    plant = Plant(PROFILE, seed=0, nominal=True,
                  effects=[fx.Delay("x", delay_s=delay_s), fx.SensorNoise("x", std_mm=NOISE_MM),
                           fx.SensorNoise("y", std_mm=NOISE_MM)])
    d = diagnose_arrays(tr.pos_mm, plant.simulate(tr).measured_mm, PROFILE.ts_s, IMPULSE)
    top = d.effects[0]
    assert (top["kind"], top["axis"]) == ("delay", "x"), d.effects
    assert top["params"]["seconds"] == pytest.approx(delay_s, rel=0.01)
    assert d.holdout_rms_mm["after"]["x"] < 1.5 * NOISE_MM


@pytest.mark.parametrize("wavelength_mm", [0.8, 0.4])
def test_a_steppers_electrical_cycle_is_named(wavelength_mm):
    """A stepper's position error repeats every 4 full steps — 0.8 mm on a 20-tooth GT2
    pulley (40 mm / 50), with a harmonic at 0.4 mm: the fine ripple of printed walls. 5 µm
    of it on X (point-to-point motion, 1 µm noise): named with its wavelength within 0.5 %
    and amplitude within 10 %, the held-out error down to the noise. With the scan stopping
    at 1 mm (before) both were `none` at a 3.7 µm residual."""
    rng = np.random.default_rng(31)
    cmd = point_to_point(rng, duration_s=20.0, ts_s=PROFILE.ts_s)
    eff = [fx.PeriodicPosition("x", wavelength_mm=wavelength_mm, amplitude_mm=0.005),
           fx.SensorNoise("x", std_mm=NOISE_MM), fx.SensorNoise("y", std_mm=NOISE_MM)]
    out = Plant(PROFILE, seed=3, effects=eff, nominal=True).simulate(
        Trajectory(ts_s=PROFILE.ts_s, pos_mm=cmd, e_mm=np.zeros(len(cmd))))
    d = diagnose_arrays(cmd, out.measured_mm, PROFILE.ts_s, IMPULSE)
    (e,) = [e for e in d.effects if e["kind"] != "none"]
    assert (e["kind"], e["axis"]) == ("periodic_position", "x"), d.effects
    assert abs(e["params"]["wavelength_mm"] - wavelength_mm) <= 0.005 * wavelength_mm
    assert abs(e["params"]["amplitude_mm"] - 0.005) <= 0.1 * 0.005
    assert d.holdout_rms_mm["after"]["x"] <= 1.1 * NOISE_MM


def test_leftover_against_closed_forms():
    """White noise σ leaves σ and nothing significant; a 40 Hz sinusoid of amplitude A on it
    leaves A/√2 beyond the noise, its peak at 40 Hz near a 38 Hz mode; a ramp is slow."""
    rng = np.random.default_rng(5)
    ts, K, sigma = 0.002, 6000, 0.0007
    t = np.arange(K) * ts
    noise = rng.normal(0.0, sigma, K)
    lo = leftover(noise, ts, 38.0)
    assert lo["noise_mm"] == pytest.approx(sigma, rel=0.05)
    assert lo["rms_mm"] == pytest.approx(sigma, rel=0.05) and not lo["significant"]
    A = 0.003
    lo = leftover(noise + A * np.sin(2 * np.pi * 40.0 * t), ts, 38.0)
    assert lo["significant"] and lo["excess_mm"] == pytest.approx(A / np.sqrt(2), rel=0.05)
    assert lo["peak_hz"] == pytest.approx(40.0, abs=0.5) and lo["slow_share"] < 0.01
    assert lo["peak_mm"] == pytest.approx(A, rel=0.1)
    lo = leftover(noise + 0.005 * t / t[-1], ts)
    assert lo["significant"] and lo["slow_share"] > 0.9
    # below the relevance floor (1 µm) nothing is significant, however clean the sensor
    lo = leftover(rng.normal(0.0, 1e-5, K) + 0.0008 * np.sin(2 * np.pi * 40.0 * t), ts)
    assert not lo["significant"]


def test_sincos_rss_is_the_least_squares_fit():
    """The closed form periodic_time ranks its peaks by equals lstsq of [sin, cos] at every
    frequency, on uniform times and on uneven ones (a position as the phase), and a sinusoid
    in the residual leaves only the noise at its own frequency."""
    rng = np.random.default_rng(11)
    K = 1500
    for u in (np.arange(K) * 0.002, np.cumsum(rng.uniform(0.0, 0.3, K))):
        r = rng.normal(0.0, 1.0, K) + 3.0 * np.sin(2 * np.pi * 7.3 * u + 0.4)
        freqs = np.array([0.5, 7.3, 11.0, 30.0])
        want = []
        for f in freqs:
            G = np.column_stack([np.sin(2 * np.pi * f * u), np.cos(2 * np.pi * f * u)])
            e = r - G @ np.linalg.lstsq(G, r, rcond=None)[0]
            want.append(e @ e)
        got = sincos_rss(r, u, freqs)
        np.testing.assert_allclose(got, want, rtol=1e-9)
        assert np.argmin(got) == 1 and got[1] / K == pytest.approx(1.0, rel=0.1)


def test_a_walking_scan_follows_a_best_at_its_grid_edge():
    """catalogue._walk: a maximum past the grid's edge (1.3, the grid 0–1) is reached by
    re-centring the grid on the edge, then refined to it; one inside the grid is found
    without walking (the points tried: the grid and the refinement's 33); one beyond reach
    stops after ``walks`` grids, at the last one's edge (within the refinement's steps)."""
    calls = []

    def f(c):
        def ev(p):
            calls.append(p)
            return -(p - c) ** 2
        return ev

    grid = np.linspace(0.0, 1.0, 9)
    p, v, n = _walk(f(1.3), grid)
    assert p == pytest.approx(1.3, abs=1e-3) and n == len(calls) == 2 * 9 + 33
    calls.clear()
    p, _, n = _walk(f(0.4), grid)
    assert p == pytest.approx(0.4, abs=1e-3) and n == len(calls) == 9 + 33
    calls.clear()
    p, _, n = _walk(f(10.0), grid, walks=4)
    assert p == pytest.approx(2.5, abs=0.02) and n == len(calls) == 4 * 9 + 33


def test_undo_response_inverts_where_the_response_carries_the_signal():
    """The regularised inverse H*/(|H|² + ε·max|H|²) the dynamics form of periodic_position
    ranks with: a pure delay (|H| = 1) comes back exactly, scaled 1/(1 + ε); a sinusoid
    through a damped mode comes back in amplitude and phase by |H|²/(|H|² + ε·max|H|²) at its
    frequency, while noise where |H| is small is not amplified beyond 1/(2√ε·max|H|)."""
    rng = np.random.default_rng(3)
    r = rng.normal(0.0, 1.0, 2000)
    got = undo_response(r, np.array([0.0, 0.0, 1.0]), eps=0.01)
    np.testing.assert_allclose(got[:-2], r[2:] / 1.01, atol=1e-12)
    ts, f0, zeta, f = 0.002, 30.0, 0.3, 12.0
    tt = np.arange(1000) * ts
    w0 = 2 * np.pi * f0
    wd = w0 * np.sqrt(1 - zeta ** 2)
    h = ts * w0 ** 2 / wd * np.exp(-zeta * w0 * tt) * np.sin(wd * tt)   # unit DC gain
    t = np.arange(6000) * ts
    x = np.sin(2 * np.pi * f * t)
    y = np.convolve(x, h)[:t.size]
    H = np.fft.rfft(h, 1 << 14)
    peak = float(np.max(np.abs(H)) ** 2)
    Hf = np.sum(h * np.exp(-2j * np.pi * f * tt))
    gain = abs(Hf) ** 2 / (abs(Hf) ** 2 + 0.01 * peak)
    mid = slice(2000, 4000)                       # away from the start's transient and the end
    u = undo_response(y, h)[mid]
    G = np.column_stack([np.sin(2 * np.pi * f * t[mid]), np.cos(2 * np.pi * f * t[mid])])
    c = np.linalg.lstsq(G, u, rcond=None)[0]
    assert np.hypot(*c) == pytest.approx(gain, rel=0.01) and abs(c[1]) < 0.01
    n = rng.normal(0.0, 1.0, 6000)
    assert np.std(undo_response(n, h)) < 1.0 / (2 * np.sqrt(0.01 * peak))


def test_a_play_on_the_response_is_named_backlash_with_the_sticking_friction_tied():
    """Our virtual machine's backlash is a play on the response, which is also what a
    friction of the carriage's own velocity makes quasi-statically (friction form ``stick``,
    lag = half the width): one model. Seed 0's log had the friction ahead by a hair of the
    held-out part (3749.8 against 3753.1 µm²); the convention names the backlash and states
    the friction as the tie (diagnose._choose), both parameters within 2 %."""
    hidden, d = run_case("backlash", 0)
    top = d.effects[0]
    assert (top["kind"], top["axis"], top["form"]) == ("backlash", hidden.axis, "output"), top
    b = hidden.params()["magnitude_mm"]
    assert abs(top["params"]["magnitude_mm"] - b) <= 0.02 * b
    tie = top["params"]["tie"]
    assert (tie["kind"], tie["params"]["form"]) == ("friction", "stick"), tie
    assert abs(tie["params"]["magnitude_mm"] - b / 2) <= 0.02 * b / 2
