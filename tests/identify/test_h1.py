"""H1 on a synthetic legacy Klipper resonance test: known modal plant, noise, clock offset."""

import numpy as np
import pytest
from scipy import signal

from gcode_feedopt.errors import ProfileError
from gcode_feedopt.identify.excitation import legacy_accel_mm_s2
from gcode_feedopt.identify.h1 import align, h1
from gcode_feedopt.identify.modal import fit_modes_complex

FS_HI, DECIM = 4000.0, 10  # simulate at 4 kHz, record at 400 Hz (Klipper raw files: ~394 Hz)


def _plant_response(a, fn_hz, zeta):
    wn = 2 * np.pi * fn_hz
    num, den = [wn**2], [1.0, 2 * zeta * wn, wn**2]
    bz, az = signal.bilinear(num, den, FS_HI)
    return signal.lfilter(bz, az, a)


@pytest.mark.parametrize("fn_hz,zeta,offset", [(42.0, 0.08, 37), (61.0, 0.12, 250)])
def test_h1_recovers_mode_with_offset_and_noise(fn_hz, zeta, offset):
    rng = np.random.default_rng(6)
    _, a = legacy_accel_mm_s2(FS_HI)
    y = _plant_response(a, fn_hz, zeta)
    fs = FS_HI / DECIM
    cmd, meas = signal.decimate(a, DECIM), signal.decimate(y, DECIM)
    # unknown start (print-time offset) and accelerometer noise of 200 mm/s^2 RMS
    meas = np.r_[rng.standard_normal(offset) * 50, meas][:len(cmd)]
    meas = meas + 200 * rng.standard_normal(len(cmd))
    cmd_al, lag = align(cmd, meas, max_lag=2000)
    assert abs(lag - offset) <= 3
    f, h, coh = h1(cmd_al, meas, fs)
    m = (f > 5) & (f < 130)
    fit = fit_modes_complex(f[m], h[m], 1, weight=coh[m], max_delay_s=4 / fs)
    assert fit.freq_hz[0] == pytest.approx(fn_hz, rel=0.02)
    assert fit.damping[0] == pytest.approx(zeta, rel=0.20)


def test_h1_too_short_is_an_error():
    with pytest.raises(ProfileError, match="too short"):
        h1(np.ones(100), np.ones(100), 400.0)
