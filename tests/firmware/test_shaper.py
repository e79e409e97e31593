"""Input shapers (firmware.shaper) against their closed forms."""

import math

import numpy as np
import pytest

from gcode_feedopt.firmware.shaper import (EI_VIBRATION, Shaper, reach_samples, residual_vibration,
                                           response, shape)


@pytest.mark.parametrize("kind", ["zv", "zvd", "mzv"])
@pytest.mark.parametrize("zeta", [0.0, 0.1, 0.2])
def test_zero_vibration_shapers_leave_no_vibration_at_their_design_point(kind, zeta):
    a, t = Shaper(kind, 42.0, zeta, centred=False).pulses()
    assert abs(a.sum() - 1) < 1e-12 and np.all(a > 0) and np.all(np.diff(t) > 0)
    assert residual_vibration(a, t, 42.0, zeta) < 1e-12
    # and a mode 30 % off the design keeps some: the shaper is tuned, not a low-pass
    assert residual_vibration(a, t, 42.0 * 1.3, zeta) > 0.05


@pytest.mark.parametrize("zeta", [0.0, 0.05, 0.1, 0.2])
def test_ei_leaves_its_tolerance_at_the_design_point_and_less_around_it(zeta):
    """EI's polynomial fit (Singhose) puts V = 5 % at the design frequency and two zeros
    either side: V below 5 % over ±15 % of it."""
    a, t = Shaper("ei", 50.0, zeta, centred=False).pulses()
    assert abs(residual_vibration(a, t, 50.0, zeta) - EI_VIBRATION) < 3e-3
    for r in (0.88, 0.92, 1.08, 1.12):
        assert residual_vibration(a, t, 50.0 * r, zeta) < EI_VIBRATION + 3e-3, r


def test_centred_pulses_have_zero_mean_time_and_a_causal_copy_is_a_pure_delay():
    c = Shaper("mzv", 40.0, 0.1, centred=True).pulses()
    k = Shaper("mzv", 40.0, 0.1, centred=False).pulses()
    assert abs(np.sum(c[0] * c[1])) < 1e-15
    assert np.allclose(c[1] - c[1][0], k[1]) and np.allclose(c[0], k[0])
    f = np.linspace(1, 200, 50)
    shift = np.exp(-2j * np.pi * f * (k[1][0] - c[1][0]))
    assert np.allclose(response(*k, f), response(*c, f) * shift)


def test_shape_keeps_a_constant_speed_and_delays_it_when_causal():
    ts = 0.002
    u = 100.0 * np.arange(400) * ts          # 100 mm/s
    a, t = Shaper("mzv", 40.0, 0.1, centred=True).pulses()
    lead, lag = reach_samples(t, ts)
    inner = slice(lag + 1, u.size - lead - 1)
    assert np.max(np.abs(shape(u, ts, a, t)[inner] - u[inner])) < 1e-9
    a, t = Shaper("zv", 40.0, 0.1, centred=False).pulses()
    mean_t = float(np.sum(a * t))
    got = shape(u, ts, a, t)[inner]
    assert np.max(np.abs(got - 100.0 * (np.arange(400)[inner] * ts - mean_t))) < 1e-9


def test_shape_of_a_sine_is_the_shapers_frequency_response():
    ts = 0.0005
    f0 = 23.0
    k = np.arange(8000)
    u = np.sin(2 * np.pi * f0 * k * ts)
    a, t = Shaper("ei", 35.0, 0.1, centred=True).pulses()
    h = response(a, t, [f0])[0]
    want = abs(h) * np.sin(2 * np.pi * f0 * k * ts + np.angle(h))
    inner = slice(100, -100)
    # linear interpolation between samples: error ≤ (2π f0 Ts)²/8 of the amplitude
    assert np.max(np.abs(shape(u, ts, a, t)[inner] - want[inner])) < (2 * math.pi * f0 * ts) ** 2 / 8


def test_independent_segments_are_shaped_apart():
    ts = 0.002
    a, t = Shaper("zvd", 30.0, 0.1, centred=True).pulses()
    rng = np.random.default_rng(0)
    u1, u2 = np.cumsum(rng.standard_normal(300)), np.cumsum(rng.standard_normal(200)) + 50
    got = shape(np.concatenate([u1, u2]), ts, a, t, segments=[0, 300])
    assert np.allclose(got, np.concatenate([shape(u1, ts, a, t), shape(u2, ts, a, t)]))
    # two columns at once are the columns apart
    both = shape(np.column_stack([u1, 2 * u1]), ts, a, t)
    assert np.allclose(both[:, 1], 2 * shape(u1, ts, a, t))


def test_bad_designs_are_refused():
    with pytest.raises(ValueError, match="frequency"):
        Shaper("mzv", 0.0).pulses()
    with pytest.raises(ValueError, match="unknown shaper type"):
        Shaper("2hump_ei", 40.0).pulses()


def test_a_configuration_mapping_is_the_shaper_it_states():
    assert Shaper.from_dict({"type": "mzv", "freq_hz": 40, "damping_ratio": 0.1,
                             "centred": False}) == Shaper("mzv", 40.0, 0.1, False)
    c = Shaper.from_dict({"type": "custom", "amplitudes": [1, 1], "times_s": [0, 0.01]})
    np.testing.assert_allclose(c.pulses()[1], [-0.005, 0.005])
