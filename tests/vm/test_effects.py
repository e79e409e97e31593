"""Each unknown effect against a hand-computed case; SPEC parsing and its errors."""

from __future__ import annotations

import numpy as np
import pytest

from gcode_feedopt.errors import FeedOptError
from gcode_feedopt.vm import effects as fx
from gcode_feedopt.vm.plant import simulate_axes

from .vm_helpers import TS, step_invariant_impulse

UNIT = {"x": np.array([1.0]), "y": np.array([1.0])}


def run(cmd_x, effects, cmd_y=None, h=UNIT):
    K = cmd_x.size
    cmd = np.column_stack([cmd_x, np.zeros(K) if cmd_y is None else cmd_y, np.zeros(K)])
    return simulate_axes(cmd, TS, h, effects, noise_rng=np.random.default_rng(0)).actual_mm


def test_play_hand_case():
    x = np.array([0.0, 1.0, 2.0, 2.0, 1.0, 0.0, 0.2, 1.0])
    # r = 0.5: rising y = max(x - r, y), falling y = min(x + r, y)
    expect = [0.0, 0.5, 1.5, 1.5, 1.5, 0.5, 0.5, 0.5]
    np.testing.assert_allclose(fx.play(x, 1.0), expect)


def test_play_matches_sample_loop():
    rng = np.random.default_rng(4)
    x = np.cumsum(rng.normal(size=5000) * (rng.random(5000) < 0.7))  # with stops
    r = 0.4
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, x.size):
        y[k] = min(x[k] + r, max(x[k] - r, y[k - 1]))
    np.testing.assert_allclose(fx.play(x, 2 * r), y, atol=1e-12)


def test_backlash_in_plant():
    cmd = np.concatenate([np.linspace(0, 10, 101), np.linspace(10, 0, 101)[1:]])
    out = run(cmd, [fx.Backlash("x", magnitude_mm=0.2)])
    np.testing.assert_allclose(out[100, 0], 9.9)  # trails by 0.1 going up
    np.testing.assert_allclose(out[-1, 0], 0.1)  # and going down


def test_friction_sign_of_commanded_velocity():
    cmd = np.concatenate([np.linspace(0, 1, 11), np.ones(5), np.linspace(1, 0, 11)[1:]])
    out = run(cmd, [fx.Friction("x", amplitude_mm=0.03)])
    err = out[:, 0] - cmd
    np.testing.assert_allclose(err[1:10], -0.03)
    np.testing.assert_allclose(err[12:15], 0.0)  # at rest
    np.testing.assert_allclose(err[17:-1], 0.03)


def test_delay_fractional_on_a_ramp():
    cmd = 5.0 + 0.1 * np.arange(100)
    out = run(cmd, [fx.Delay("x", delay_s=2.5 * TS)])
    np.testing.assert_allclose(out[3:, 0], cmd[3:] - 0.25, atol=1e-12)
    np.testing.assert_allclose(out[:3, 0], [5.0, 5.0, 5.0])


def test_gain_about_origin():
    cmd = np.linspace(10, 20, 50)
    out = run(cmd, [fx.Gain("x", scale=1.02)])
    np.testing.assert_allclose(out[:, 0], 1.02 * cmd, atol=1e-12)


def test_periodic_time_is_the_papers_sinusoid():
    e = fx.parse_effect("sinusoid:axis=y")
    assert isinstance(e, fx.PeriodicTime)
    assert e.amplitude_mm == 0.2 and e.frequency_hz * 2 * np.pi == pytest.approx(733.0)
    out = run(np.zeros(300), [e], cmd_y=np.full(300, 3.0))
    t = np.arange(300) * TS
    np.testing.assert_allclose(out[:, 1], 3.0 + 0.2 * np.sin(733.0 * t), atol=1e-12)
    np.testing.assert_allclose(out[:, 0], 0.0)


def test_periodic_position_of_commanded_position():
    cmd = np.linspace(0, 80, 400)
    out = run(cmd, [fx.PeriodicPosition("x", wavelength_mm=40.0, amplitude_mm=0.05, phase_rad=0.3)])
    np.testing.assert_allclose(out[:, 0], cmd + 0.05 * np.sin(2 * np.pi * cmd / 40 + 0.3), atol=1e-12)


def test_cross_coupling_from_the_other_axis():
    y = np.linspace(50, 60, 100)
    out = run(np.full(100, 7.0), [fx.CrossCoupling("x", from_axis="y", coefficient=0.02)], cmd_y=y)
    np.testing.assert_allclose(out[:, 0], 7.0 + 0.02 * (y - 50), atol=1e-12)
    np.testing.assert_allclose(out[:, 1], y, atol=1e-12)


def test_resonance_shift_moves_the_mode():
    """Time-scaling h by r = f1/f0 turns a (wn, zeta) mode into (r wn, zeta)."""
    zeta = 0.08
    h40 = step_invariant_impulse(2 * np.pi * 40, zeta, 1500)
    assert fx.dominant_mode_hz(h40, TS) == pytest.approx(40 * np.sqrt(1 - 2 * zeta**2), rel=0.01)
    shifted = fx.ResonanceShift("x", frequency_hz=50.0).apply(h40, TS, mode_hz=40.0)
    h50 = step_invariant_impulse(2 * np.pi * 50, zeta, shifted.size)
    # cubic interpolation of a 10-samples-per-period step response: 0.08 % measured, 0.5 % allowed
    assert np.max(np.abs(shifted - h50)) < 0.005 * np.max(np.abs(h50))
    assert shifted.sum() == pytest.approx(h40.sum(), abs=1e-12)
    # in the plant: the mode shifts, so does the step response's ringing
    cmd = np.concatenate([np.zeros(10), np.ones(1000)])
    out = run(cmd, [fx.ResonanceShift("x", frequency_hz=50.0)], h={"x": h40, "y": h40})
    peak_k = np.argmax(out[:, 0]) - 10
    t_peak = np.pi / (2 * np.pi * 50 * np.sqrt(1 - zeta**2))
    assert peak_k * TS == pytest.approx(t_peak, abs=1.5 * TS)


@pytest.mark.parametrize("kind", sorted(fx.EFFECT_TYPES))
def test_spec_round_trip(kind):
    rng = np.random.default_rng(11)
    e = fx.random_effect(rng, kind=kind, mode_hz=40.0)
    assert fx.parse_effect(e.to_spec()) == e
    assert fx.effect_from_dict(e.to_dict()) == e


@pytest.mark.parametrize("spec, match", [
    ("sinus:axis=x", r"unknown kind 'sinus' \(did you mean 'sinusoid'\?\)"),
    ("backlash:axis=x,magnitude=0.1", r"no parameter 'magnitude' \(did you mean 'magnitude_mm'\?\)"),
    ("backlash:axis=x", r"missing magnitude_mm; e\.g\. backlash:axis=x,magnitude_mm=0\.05"),
    ("gain:scale=1.01", r"missing axis"),
    ("delay:axis=x,delay_s=fast", r"delay_s='fast' is not a number"),
    ("delay:axis=z,delay_s=0.01", r"axis='z' is not supported"),
    ("friction:axis=x,amplitude_mm=-1", r"amplitude_mm=-1.0 must be a finite number > 0"),
    ("cross_coupling:axis=x,from_axis=x,coefficient=0.1", r"from_axis='x' must be the other axis"),
    ("periodic_time:axis=x,frequency_hz", r"'frequency_hz' is not key=value"),
])
def test_spec_errors(spec, match):
    with pytest.raises(FeedOptError, match=match):
        fx.parse_effect(spec)


def test_spec_aliases():
    e = fx.parse_effect("sinusoid:axis=x,amp_mm=0.05,freq_hz=116.7")
    assert e == fx.PeriodicTime("x", frequency_hz=116.7, amplitude_mm=0.05)
    assert fx.parse_effect("delay:axis=y,delay_ms=4") == fx.Delay("y", delay_s=0.004)


def test_resonance_shift_above_nyquist_refused():
    h = step_invariant_impulse(2 * np.pi * 40, 0.1, 200)
    with pytest.raises(FeedOptError, match="Nyquist"):
        fx.ResonanceShift("x", frequency_hz=300.0).apply(h, TS)


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=60, deadline=None)
@given(steps=st.lists(st.sampled_from([-1.0, -0.3, 0.0, 0.0, 0.2, 1.0]), min_size=1, max_size=80),
       width=st.floats(0.0, 2.0))
def test_play_run_form_equals_sample_recursion(steps, width):
    """Two implementations of the play operator agree on any walk with stops (to 1e-12)."""
    x = np.concatenate([[3.0], 3.0 + np.cumsum(steps)])
    r = width / 2
    y = [x[0]]
    for xk in x[1:]:
        y.append(min(xk + r, max(xk - r, y[-1])))
    np.testing.assert_allclose(fx.play(x, width), y, atol=1e-12)
