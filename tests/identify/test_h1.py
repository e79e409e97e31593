"""H1 with coherence and interleaved subsets, integer alignment (pure numerics)."""

import numpy as np
import pytest
from scipy import signal

from gcode_feedopt.errors import ProfileError
from gcode_feedopt.identify.h1 import align, h1, h1_sets

FS = 400.0


def _plant(fn, zeta):
    wn = 2 * np.pi * fn
    return signal.bilinear([wn**2], [1.0, 2 * zeta * wn, wn**2], FS)


def test_h1_sets_recover_known_frf_from_white_noise():
    rng = np.random.default_rng(5)
    x = rng.standard_normal(60_000)
    b, a = _plant(50.0, 0.1)
    y = signal.lfilter(b, a, x) + 0.05 * rng.standard_normal(x.size)
    r = h1_sets(x, y, FS, nperseg=512, n_sets=4)
    m = (r.freq_hz > 5) & (r.freq_hz < 150)
    _, true = signal.freqz(b, a, worN=r.freq_hz[m], fs=FS)
    assert np.max(np.abs(r.h[m] - true)) < 0.05 * np.max(np.abs(true))
    assert np.median(r.coherence[m]) > 0.95
    assert r.h_sets.shape == (4, len(r.freq_hz))
    for hs in r.h_sets:
        assert np.max(np.abs(hs[m] - true)) < 0.1 * np.max(np.abs(true))
    f, h, coh = h1(x, y, FS, nperseg=512)
    np.testing.assert_allclose(h, r.h)


def test_align_finds_integer_offset():
    rng = np.random.default_rng(2)
    cmd = rng.standard_normal(5000)
    meas = np.r_[np.zeros(123), cmd][:5000] + 0.1 * rng.standard_normal(5000)
    out, lag = align(cmd, meas, max_lag=500)
    assert lag == 123
    np.testing.assert_allclose(out[123:], cmd[:5000 - 123])


def test_h1_too_short_is_an_error():
    with pytest.raises(ProfileError, match="too short"):
        h1(np.ones(100), np.ones(100), 400.0)
