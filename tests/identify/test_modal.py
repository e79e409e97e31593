"""Modal fitting recovers known modes from synthetic FRFs (seeded noise)."""

import numpy as np
import pytest

from gcode_feedopt.errors import ProfileError
from gcode_feedopt.identify.modal import fit_modes_complex, fit_modes_magnitude, modal_response

FREQ_HZ = np.arange(0.0, 150.0, 0.5)


@pytest.mark.parametrize("modes", [
    ([38.0], [0.08], [1.0]),
    ([42.0, 61.0], [0.06, 0.12], [0.7, 0.3]),
])
def test_complex_fit_recovers_modes(modes):
    fn, zeta, gain = (np.array(v) for v in modes)
    rng = np.random.default_rng(1)
    h = modal_response(FREQ_HZ, fn, zeta, gain)
    noisy = h + 0.02 * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape))
    fit = fit_modes_complex(FREQ_HZ, noisy, n_modes=len(fn))
    np.testing.assert_allclose(fit.freq_hz, fn, rtol=0.02)
    np.testing.assert_allclose(fit.damping, zeta, rtol=0.20)


@pytest.mark.parametrize("modes", [
    ([37.0], [0.1], [1.0]),
    ([45.0, 59.0], [0.08, 0.1], [0.6, 0.4]),
])
def test_magnitude_fit_recovers_modes(modes):
    fn, zeta, gain = (np.array(v) for v in modes)
    rng = np.random.default_rng(2)
    mag = 5e3 * np.abs(modal_response(FREQ_HZ, fn, zeta, gain))
    noisy = mag * np.exp(0.03 * rng.standard_normal(mag.shape))  # 3 % multiplicative noise
    fit = fit_modes_magnitude(FREQ_HZ, noisy, n_modes=len(fn))
    np.testing.assert_allclose(fit.freq_hz, fn, rtol=0.02)
    np.testing.assert_allclose(fit.damping, zeta, rtol=0.20)
    assert fit.scale == pytest.approx(5e3, rel=0.1)


def test_too_few_points_is_an_error():
    with pytest.raises(ProfileError, match="frequency points"):
        fit_modes_complex(FREQ_HZ[:5], np.ones(5, complex), n_modes=1)
