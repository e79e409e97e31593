"""Alignment by cross-correlation (offset and clock rate) and H1 FRF estimates with coherence (pure).

Clock model: the recording's time axis tau (s from its first sample) and the excitation's time
t_c (s from the start of the test) are related by ``t_c = (1 - slope) * tau - offset_s``, i.e.
the command appears in the recording ``offset_s`` late and the sensor clock runs fast by
``rate_error = 1/(1 - slope) - 1`` (negative: slow). See ``estimate_clock``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

from ..errors import ProfileError


def align(cmd, meas, max_lag: int):
    """Shift ``cmd`` so it best matches ``meas`` (cross-correlation); returns (cmd_aligned, lag).

    Both (K,) at the same sample rate; lag > 0 means the measurement starts later.
    """
    lag = _peak_lag(meas, cmd, -max_lag, max_lag)
    lag = int(round(lag))
    out = np.zeros_like(meas, dtype=float)
    if lag >= 0:
        n = min(len(cmd), len(meas) - lag)
        out[lag:lag + n] = cmd[:n]
    else:
        n = min(len(cmd) + lag, len(meas))
        out[:n] = cmd[-lag:-lag + n]
    return out, lag


def _peak_lag(meas, cmd, lo: float, hi: float, with_value: bool = False):
    """Lag (samples, sub-sample by a parabola) of the largest |xcorr| with lo <= lag <= hi."""
    c = signal.correlate(meas - meas.mean(), cmd - cmd.mean(), mode="full", method="fft")
    lags = signal.correlation_lags(len(meas), len(cmd), mode="full")
    ok = np.flatnonzero((lags >= lo) & (lags <= hi))
    if len(ok) == 0:
        raise ProfileError("alignment: recording and excitation do not overlap; "
                           "check the --freq-*/--hz-per-sec options")
    i = ok[np.argmax(np.abs(c[ok]))]
    lag = float(lags[i])
    if 0 < i < len(c) - 1:
        y0, y1, y2 = np.abs(c[i - 1:i + 2])
        den = y0 - 2 * y1 + y2
        if den < 0:
            lag += 0.5 * (y0 - y2) / den
    if with_value:
        norm = np.sqrt(np.sum((meas - meas.mean())**2) * np.sum((cmd - cmd.mean())**2))
        return lag, float(c[i] / norm) if norm > 0 else 0.0
    return lag


@dataclass(frozen=True)
class Clock:
    """Fitted relation between recording time and excitation time (see module docstring)."""

    offset_s: float
    slope: float
    score: float  # normalised cross-correlation of the aligned command with the recording

    @property
    def rate_error(self) -> float:
        return 1.0 / (1.0 - self.slope) - 1.0

    def cmd_time(self, tau_s):
        return (1.0 - self.slope) * np.asarray(tau_s) - self.offset_s


def estimate_clock(cmd_t, cmd_a, meas, fs_hz: float, freq_at, window_s: float = 2.0,
                   hop_s: float = 0.5, clock: Clock | None = None) -> Clock:
    """Offset and clock rate of ``meas`` (K,) at ``fs_hz`` against the reference ``(cmd_t, cmd_a)``.

    ``cmd_t`` uniform (any rate: oversample it, as the command is linearly interpolated to
    the recording's instants, and band-limit it below fs_hz/2); ``freq_at(t_c)`` the frequency the test sweeps at
    excitation time t_c. The cross-correlation of the first 20 Hz of the sweep gives the
    first offset (it must be right within half a period at freq_start). Then, window by window in time
    order, the phase of the cross-spectrum around the swept frequency gives the residual
    lag modulo one period; it is unwrapped *along time* (from the slow start of the sweep,
    where a period is 200 ms, the lag changes by far less than half a period from one window
    to the next), and a straight line through lag(tau) (weighted by the window's cross power)
    gives offset and slope. Windowed correlation peaks cannot do this: a few Hz swept leave
    neighbouring periods almost as high as the true peak. The reference should be the
    predicted response (the command through a fitted model), else the plant's own phase
    (-90 deg at a mode) bends the line.
    """
    tau = np.arange(len(meas)) / fs_hz
    # first offset from the slow start of the sweep (first 20 Hz): periods of 50-200 ms,
    # below the modes (little plant lag), too short for a clock-rate error to smear it
    f_c = freq_at(cmd_t)
    seg = np.flatnonzero(np.isfinite(f_c) & (f_c <= np.nanmin(f_c) + 20.0))
    if len(seg) < 2:
        seg = np.arange(len(cmd_a))
    t_seg = np.arange(cmd_t[seg[0]], cmd_t[seg[-1]], 1.0 / fs_hz)   # at the recording's rate
    lag, sign = _peak_lag(meas, np.interp(t_seg, cmd_t, cmd_a), -len(t_seg), len(meas),
                          with_value=True)
    if clock is None:
        clock = Clock(offset_s=lag / fs_hz - t_seg[0], slope=0.0, score=0.0)
    sign = 1.0 if sign >= 0 else -1.0   # a projection against the motion: phase + 180 deg
    n_win, n_hop = int(window_s * fs_hz), int(hop_s * fs_hz)
    win = signal.windows.hann(n_win)
    fk = np.fft.rfftfreq(n_win, 1.0 / fs_hz)
    for _ in range(2):
        ref = np.interp(clock.cmd_time(tau), cmd_t, cmd_a, left=0.0, right=0.0)
        centres, lags, weights = [], [], []
        prev = 0.0
        for start in range(0, len(meas) - n_win + 1, n_hop):
            sl = slice(start, start + n_win)
            r = np.fft.rfft((ref[sl] - ref[sl].mean()) * win)
            m = sign * np.fft.rfft((meas[sl] - meas[sl].mean()) * win)
            f_c = float(freq_at(clock.cmd_time(tau[start + n_win // 2])))
            if not np.isfinite(f_c) or f_c <= 0:
                continue
            band = np.abs(fk - f_c) <= max(1.5, 2.5 / window_s)
            cross = np.sum(np.conj(r[band]) * m[band])
            if abs(cross) == 0:
                continue
            # meas(tau) = ref(tau - L): phase(conj(R) M) = -2 pi f L
            lag = -np.angle(cross) / (2 * np.pi * f_c)
            period = 1.0 / f_c
            lag += period * np.round((prev - lag) / period)   # unwrap along time
            prev = lag
            centres.append(tau[start + n_win // 2])
            lags.append(lag)
            weights.append(abs(cross) / np.sqrt(np.sum(np.abs(r[band])**2) * np.sum(np.abs(m[band])**2)))
        if len(centres) < 3:
            break
        b, a = np.polyfit(centres, lags, 1, w=np.asarray(weights))
        clock = Clock(clock.offset_s + (1 - clock.slope) * a,
                      1 - (1 - clock.slope) * (1 - b), 0.0)
    ref = np.interp(clock.cmd_time(tau), cmd_t, cmd_a, left=0.0, right=0.0)
    mm, cc = meas - meas.mean(), ref - ref.mean()
    den = np.sqrt(np.sum(mm**2) * np.sum(cc**2))
    return Clock(clock.offset_s, clock.slope, float(np.sum(mm * cc) / den) if den > 0 else 0.0)


@dataclass(frozen=True)
class H1Sets:
    """H1 estimates from short windows: all of them, and ``n_sets`` interleaved subsets.

    freq_hz (F,); h (F,) complex and coherence (F,) over all windows; h_sets (S, F) with
    window j in set j mod S (disjoint data, each covering the whole sweep); sxx (F,) input
    auto-spectrum summed over windows (to find where the excitation has power).
    """

    freq_hz: np.ndarray
    h: np.ndarray
    coherence: np.ndarray
    h_sets: np.ndarray
    sxx: np.ndarray


def h1_sets(cmd, meas, fs_hz: float, nperseg: int = 512, n_sets: int = 4) -> H1Sets:
    """H1 = sum S_xy / sum S_xx over Hann windows (75 % overlap), per interleaved subset too."""
    if len(meas) < 4 * nperseg:
        raise ProfileError(f"recording too short: {len(meas)} samples < {4 * nperseg}; "
                           f"record the whole resonance test")
    kw = dict(fs=fs_hz, window="hann", nperseg=nperseg, noverlap=3 * nperseg // 4,
              boundary=None, padded=False, detrend="constant")
    f, _, x = signal.stft(cmd, **kw)
    _, _, y = signal.stft(meas, **kw)
    sxx, syy, sxy = np.abs(x)**2, np.abs(y)**2, np.conj(x) * y
    tot_xx, tot_yy, tot_xy = sxx.sum(1), syy.sum(1), sxy.sum(1)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = np.where(tot_xx > 0, tot_xy / tot_xx, 0)
        coh = np.where(tot_xx * tot_yy > 0, np.abs(tot_xy)**2 / (tot_xx * tot_yy), 0)
        sets = []
        for s in range(n_sets):
            xx, xy = sxx[:, s::n_sets].sum(1), sxy[:, s::n_sets].sum(1)
            sets.append(np.where(xx > 0, xy / xx, 0))
    return H1Sets(f, h, np.clip(coh.real, 0, 1), np.array(sets), tot_xx)


def h1(cmd, meas, fs_hz: float, nperseg: int = 1024):
    """H1 = S_xy / S_xx and coherence -> (freq_hz (F,), H (F,) complex, coh (F,))."""
    r = h1_sets(cmd, meas, fs_hz, nperseg=nperseg, n_sets=1)
    return r.freq_hz, r.h, r.coherence
