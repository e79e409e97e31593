"""H1 FRF estimate with coherence, after aligning the command by cross-correlation (pure)."""

from __future__ import annotations

import numpy as np
from scipy import signal

from ..errors import ProfileError


def align(cmd, meas, max_lag: int):
    """Shift ``cmd`` so it best matches ``meas`` (cross-correlation); returns (cmd_aligned, lag).

    Both (K,) at the same sample rate; lag > 0 means the measurement starts later.
    """
    c = signal.correlate(meas - meas.mean(), cmd - cmd.mean(), mode="full", method="fft")
    lags = signal.correlation_lags(len(meas), len(cmd), mode="full")
    ok = np.abs(lags) <= max_lag
    lag = int(lags[ok][np.argmax(np.abs(c[ok]))])
    out = np.zeros_like(meas)
    if lag >= 0:
        n = min(len(cmd), len(meas) - lag)
        out[lag:lag + n] = cmd[:n]
    else:
        n = min(len(cmd) + lag, len(meas))
        out[:n] = cmd[-lag:-lag + n]
    return out, lag


def h1(cmd, meas, fs_hz: float, nperseg: int = 1024):
    """H1 = S_xy / S_xx and coherence -> (freq_hz (F,), H (F,) complex, coh (F,))."""
    if len(meas) < 4 * nperseg:
        raise ProfileError(f"recording too short: {len(meas)} samples < {4 * nperseg}; "
                           f"record the whole resonance test")
    f, sxx = signal.welch(cmd, fs_hz, nperseg=nperseg)
    _, sxy = signal.csd(cmd, meas, fs_hz, nperseg=nperseg)
    _, coh = signal.coherence(cmd, meas, fs_hz, nperseg=nperseg)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(sxx > 0, sxy / sxx, 0)
    return f, h, coh
