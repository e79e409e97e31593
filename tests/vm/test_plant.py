"""Plant against closed forms: a 2nd-order mode's step response, a pure delay, a gain."""

from __future__ import annotations

import numpy as np
import pytest

from gcode_feedopt.vm import effects as fx
from gcode_feedopt.vm.plant import Plant, respond, simulate_axes
from gcode_feedopt.vm.trajectory import Trajectory

from .vm_helpers import TS, second_order_step, step_invariant_impulse


def test_second_order_step_matches_closed_form():
    f_hz, zeta = 40.0, 0.1
    wn = 2 * np.pi * f_hz
    h = step_invariant_impulse(wn, zeta, 2000)
    k0, x0, amp = 100, 12.5, 2.0
    cmd = np.full(3000, x0)
    cmd[k0:] += amp
    x = respond(cmd, h)
    t = (np.arange(3000) - k0) * TS
    expect = x0 + amp * np.where(t >= 0, second_order_step(np.maximum(t, 0), wn, zeta), 0.0)
    np.testing.assert_allclose(x, expect, atol=1e-9)
    # overshoot exp(-zeta pi / sqrt(1 - zeta^2)) within the sampling of the peak
    overshoot = (x.max() - (x0 + amp)) / amp
    assert overshoot == pytest.approx(np.exp(-zeta * np.pi / np.sqrt(1 - zeta**2)), rel=0.02)
    # 2 % settling time 4 / (zeta wn) ~ 0.159 s: settled after 1.3x that, not before 0.7x
    err = np.abs(x - (x0 + amp)) / amp
    assert err[k0 + int(1.3 * 4 / (zeta * wn) / TS):].max() < 0.02
    assert err[k0 + int(0.7 * 4 / (zeta * wn) / TS):].max() > 0.02
    # DC gain 1: the end value is the command
    assert x[-1] == pytest.approx(x0 + amp, abs=1e-9)


def test_rest_stays_at_rest_whatever_the_dc_gain():
    h = np.array([0.5, 0.3, 0.1])  # DC gain 0.9
    x = respond(np.full(50, 37.0), h)
    np.testing.assert_array_equal(x, 37.0)


def test_pure_delay_and_gain_impulses():
    rng = np.random.default_rng(1)
    cmd = np.cumsum(rng.normal(size=500)) + 5.0
    d = 7
    h = np.zeros(20)
    h[d] = 1.0
    x = respond(cmd, h)
    np.testing.assert_allclose(x[d:], cmd[:-d], atol=1e-12)
    np.testing.assert_allclose(x[:d], cmd[0], atol=1e-12)
    g = 0.8
    x = respond(cmd, g * np.eye(1)[0])
    np.testing.assert_allclose(x, cmd[0] + g * (cmd - cmd[0]), atol=1e-12)


def test_fft_convolution_matches_direct_sum():
    rng = np.random.default_rng(2)
    cmd = np.cumsum(rng.normal(size=3000))
    h = rng.normal(size=150)
    direct = cmd[0] + np.convolve(cmd - cmd[0], h)[:3000]
    np.testing.assert_allclose(respond(cmd, h), direct, atol=1e-10)


def _traj(cmd):
    return Trajectory(ts_s=TS, pos_mm=cmd, e_mm=np.zeros(cmd.shape[0]))


def _cmd(K=4000, seed=3):
    t = np.arange(K) * TS
    return np.column_stack([20 + 10 * np.sin(2 * np.pi * 0.7 * t), 30 + 8 * np.cos(2 * np.pi * 1.1 * t),
                            0.2 + 0.01 * t])


def test_plant_from_impulse_z_ideal_and_unit_dc_gain():
    h = step_invariant_impulse(2 * np.pi * 40, 0.1, 400) * 0.97  # DC gain 0.97
    cmd = _cmd()
    cmd[2000:, :2] = cmd[2000, :2]  # move, then hold for 4 s
    out = Plant.from_impulse(TS, {"x": h, "y": h}, unit_dc_gain=True).run(_traj(cmd))
    np.testing.assert_array_equal(out[:, 2], cmd[:, 2])
    # settled at the command: DC gain 1 after scaling
    np.testing.assert_allclose(out[-1, :2], cmd[-1, :2], atol=1e-9)
    # unscaled, the same draw ends 3 % of the travel short
    raw = Plant.from_impulse(TS, {"x": h, "y": h}).run(_traj(cmd))
    np.testing.assert_allclose(raw[-1, :2], cmd[0, :2] + 0.97 * (cmd[-1, :2] - cmd[0, :2]), atol=1e-9)


def test_effect_stage_order_gain_then_additive():
    """gain (linear stage) scales the convolution only, not a periodic_time added later."""
    cmd = _cmd()
    h = np.array([1.0])
    eff = [fx.PeriodicTime("x", frequency_hz=50.0, amplitude_mm=0.1), fx.Gain("x", scale=1.01)]
    out = simulate_axes(cmd, TS, {"x": h, "y": h}, eff).actual_mm
    t = np.arange(cmd.shape[0]) * TS
    np.testing.assert_allclose(out[:, 0], 1.01 * cmd[:, 0] + 0.1 * np.sin(2 * np.pi * 50 * t), atol=1e-12)
    np.testing.assert_allclose(out[:, 1], cmd[:, 1], atol=1e-12)


def test_noise_only_in_measurement_and_seeded():
    cmd = _cmd()
    h = np.array([1.0])
    noise = fx.SensorNoise("y", std_mm=0.01)
    p1 = Plant.from_impulse(TS, {"x": h, "y": h}, [noise], seed=5)
    p2 = Plant.from_impulse(TS, {"x": h, "y": h}, [noise], seed=5)
    o1, o2 = p1.simulate(_traj(cmd)), p2.simulate(_traj(cmd))
    np.testing.assert_array_equal(o1.measured_mm, o2.measured_mm)
    np.testing.assert_allclose(o1.actual_mm[:, :2], cmd[:, :2], atol=1e-12)
    r = o1.measured_mm[:, 1] - o1.actual_mm[:, 1]
    # std of 4000 Gaussian samples: within 5 standard errors (sigma / sqrt(2K) relative)
    assert np.std(r) == pytest.approx(0.01, rel=5 / np.sqrt(2 * r.size))
    np.testing.assert_array_equal(o1.measured_mm[:, 0], o1.actual_mm[:, 0])


def test_ts_mismatch_is_refused():
    h = np.array([1.0])
    plant = Plant.from_impulse(TS, {"x": h, "y": h})
    with pytest.raises(ValueError, match="Ts="):
        plant.run(Trajectory(ts_s=0.001, pos_mm=_cmd(10), e_mm=np.zeros(10)))


def test_plant_from_profile_is_one_seeded_draw():
    from gcode_feedopt.profile import load_profile

    prof = load_profile("ender3pro")
    a, b = Plant(prof, seed=4), Plant(prof, seed=4, effects=[fx.Gain("x", scale=1.01)])
    c = Plant(prof, seed=5)
    for ax in ("x", "y"):
        np.testing.assert_array_equal(a.impulse[ax], b.impulse[ax])  # an effect never changes the draw
        assert a.impulse[ax].sum() == pytest.approx(1.0, abs=1e-12)
        assert a.impulse[ax].size == prof.twin.n_taps
        assert np.max(np.abs(a.impulse[ax] - c.impulse[ax])) > 1e-4  # another seed, another machine
    assert np.max(np.abs(a.impulse["x"] - a.impulse["y"])) > 1e-3  # axes drawn independently


def test_resonance_shift_moves_the_measured_peak_of_a_profile_draw():
    from gcode_feedopt.profile import load_profile

    prof = load_profile("ender3pro")
    K = 3000
    cmd = np.zeros((K, 3))
    cmd[10:, 0] = 1.0
    plant = Plant(prof, seed=2, effects=[fx.ResonanceShift("x", frequency_hz=45.0)])
    out = plant.simulate(Trajectory(ts_s=prof.ts_s, pos_mm=cmd, e_mm=np.zeros(K)))
    # the step response's derivative is h: its |H| peak is where the effect put it (FFT bin 0.03 Hz)
    assert fx.dominant_mode_hz(np.diff(out.actual_mm[:, 0], prepend=0.0), prof.ts_s) == pytest.approx(45.0, abs=0.1)


def test_nominal_plant_is_the_twin_mean_response():
    from gcode_feedopt.profile import load_profile
    from gcode_feedopt.twin.physics import axis_impulse

    prof = load_profile("ender3pro")
    plant = Plant(prof, seed=9, nominal=True)
    mean = axis_impulse(prof, "x").mean
    assert mean.sum() == pytest.approx(1.0, abs=1e-12)  # the DC gain is pinned, not rescaled
    np.testing.assert_allclose(plant.impulse["x"], mean, atol=1e-12)
