"""FRFs and modes from a Klipper raw accelerometer recording of a resonance test (pure numerics).

Steps (``analyse_raw``):
1. resample the recording onto a uniform grid at its median rate (its time column is used,
   so jitter and gaps do not shift samples);
2. band-pass (3 Hz .. 0.45 fs: gravity and offsets go) and project the three axes on the
   direction of motion (``_align``: the per-axis H1 just above freq_start, where the drive is
   rigid; the principal axis is only the starting point);
3. build Klipper's commanded acceleration (``excitation``; generator given, or detected:
   'current' when the recording holds the slow sweeping square wave (``sweep_ratio``; the
   two generators' chirps are nearly the same, the coherence barely tells them apart)) and
   align it: offset and sensor clock rate (``h1.estimate_clock``), finally against the
   command filtered through the fitted model;
4. H1 with coherence over short windows; the windows are dealt into ``n_sets`` interleaved
   subsets, each an FRF of the whole sweep from disjoint data (the spread);
5. modal fit of |H1| over all windows (weights = coherence; log-magnitude residual, free
   scale, H(0) = 1, minimum phase) and of each subset; the profile's FRF rows are the subset
   models. Why magnitude and not the complex H1: on the real Voron recordings the H1 phase
   wanders by tens of degrees between neighbouring bins even at 10-30 Hz, below every mode,
   where |H| is a steady 1.0 (docs/identification.md): ms-level timing errors (the sensor's
   time stamps are estimated by Klipper, or the planner's timing differs from the model) that
   scramble the phase but leave the magnitude and coherence usable.

Acceleration -> position: the accelerometer measures the toolhead's actual acceleration
``a(t) = x''(t)`` and the command is the planned acceleration ``c''(t)``. For a linear plant
``X(w) = H(w) C(w)``, so ``A(w) / C''(w) = (-w^2 X) / (-w^2 C) = H(w)``: the acceleration-
to-acceleration H1 *is* the commanded -> actual position FRF, no integration needed. What the
recording cannot give is H near 0 Hz (no excitation below freq_start, gravity removed): the
model's H(0) = 1 (a rigid drive follows a slow command) stands in, checked against the
fitted level of |H| (``fit.scale``: far from 1 means a wrong --accel-per-hz).

Warnings (one line each) are returned, not printed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from ..errors import ProfileError
from .excitation import GENERATORS, Excitation, duration_s, freq_at, sampled_accel
from .h1 import Clock, H1Sets, estimate_clock, h1_sets
from .modal import fit_modes_magnitude

#: median coherence over the band below which the data is called poor
LOW_COHERENCE = 0.5
#: a recording shorter than this fraction of the test duration is "too short"
SHORT_FRACTION = 0.9
#: accelerometer full scale assumed for the clipping check (ADXL345/LIS2DW/MPU at +-16 g)
FULL_SCALE_MM_S2 = 16 * 9806.65


@dataclass(frozen=True)
class RawResult:
    """Everything ``analyse_raw`` found about one recording."""

    excitation: Excitation
    fs_hz: float
    direction: np.ndarray          # (3,) unit vector in the sensor's axes
    clock: Clock
    h1: H1Sets
    band: np.ndarray               # (F,) bool: bins inside the excited band
    fit: object                    # ModalFit of |H1| over all windows (scale = |H| level)
    set_fits: list                 # ModalFit per interleaved subset
    warnings: list = field(default_factory=list)
    scores: dict = field(default_factory=dict)


def resample_uniform(t_s, acc):
    """(t (K,), acc (K,3)) with non-uniform times -> (fs_hz, acc_uniform (K',3))."""
    t_s = np.asarray(t_s, float)
    dt = np.diff(t_s)
    if len(t_s) < 2 or np.any(dt <= 0):
        bad = int(np.argmax(dt <= 0)) + 2 if len(dt) else 1
        raise ProfileError(f"raw recording: time column not increasing (data row {bad}); "
                           f"pass the file as Klipper wrote it")
    fs = 1.0 / float(np.median(dt))
    tu = t_s[0] + np.arange(int((t_s[-1] - t_s[0]) * fs) + 1) / fs
    return fs, np.column_stack([np.interp(tu, t_s, acc[:, k]) for k in range(acc.shape[1])])


def check_clipping(acc) -> list[str]:
    """Warnings for axes that look clipped: at the sensor's full scale, or flat at their extreme."""
    out = []
    for k, name in enumerate("xyz"[:acc.shape[1]]):
        a = acc[:, k]
        peak = float(np.max(np.abs(a)))
        vals = np.unique(a)
        lsb = float(np.min(np.diff(vals))) if len(vals) > 1 else 0.0
        n_at = int(np.sum(np.abs(a) >= peak - 0.5 * lsb))
        if peak >= 0.97 * FULL_SCALE_MM_S2 or n_at >= 5:
            out.append(f"accel_{name} looks clipped ({n_at} samples at |a| = {peak:.0f} mm/s^2); "
                       f"lower --accel-per-hz (ACCEL_PER_HZ) or raise the sensor range")
    return out


#: band above freq_start whose per-axis H1 defines the direction of motion (below the modes)
DIRECTION_BAND_HZ = 25.0


#: measured / expected amplitude of the sweeping fundamental above which 'current' is detected
SWEEP_DETECT = 0.3


def sweep_ratio(proj, fs_hz: float, ex: Excitation) -> float:
    """Amplitude of the recording ``proj`` (K,) at 1/sweeping_period over that of the
    sweeping square wave's fundamental (4/pi * sweeping_accel); ~0 for the legacy test."""
    f0 = 1.0 / ex.sweeping_period_s
    x = signal.detrend(proj)
    t = np.arange(len(x)) / fs_hz
    amp = 2.0 * abs(np.mean(x * np.exp(-2j * np.pi * f0 * t)))
    return float(amp / (4.0 / np.pi * ex.sweeping_accel_mm_s2))


#: the command is built at this multiple of the recording's rate, then linearly interpolated
#: to the (clock-corrected) sample instants; at the recording's own rate linear
#: interpolation would attenuate 67 Hz by up to 14 % (cos(pi f / fs) at half a sample)
REF_OVERSAMPLE = 8


def reference(ex: Excitation, fs_hz: float):
    """Commanded acceleration at REF_OVERSAMPLE * fs_hz, low-passed at 0.45 fs_hz (no aliasing
    when sampled at the recording's instants) and high-passed at 3 Hz like the recording,
    1 s of rest either side -> (t_s, accel)."""
    fs_ref = REF_OVERSAMPLE * fs_hz
    t, a = sampled_accel(ex, fs_ref, oversample=4, pad_s=1.0)
    sos = signal.butter(8, 0.45 * fs_hz, fs=fs_ref, output="sos")
    a = signal.sosfiltfilt(sos, a)
    # the recording's band-pass too (3 Hz high-pass), so the ratio H1 sees the same filter
    sos = signal.butter(2, 3.0, btype="highpass", fs=fs_ref, output="sos")
    return t, signal.sosfiltfilt(sos, a)


def _align(ex: Excitation, acc_f, fs, nperseg):
    """Align ``ex`` with the band-passed 3-axis ``acc_f`` -> (clock, cmd on the grid, meas, d).

    First on the principal-axis projection, then the direction is re-estimated as the
    per-axis H1 averaged over the DIRECTION_BAND_HZ above freq_start (rigid motion: below
    the modes every axis sees the commanded acceleration times its direction cosine; the
    principal axis is dominated by the resonances, which may rock in another direction),
    and the alignment is repeated on that projection.
    """
    cmd_t, cmd_a = reference(ex, fs)
    _, vecs = np.linalg.eigh(np.cov(acc_f.T))
    d = vecs[:, -1]
    tau = np.arange(len(acc_f)) / fs
    fa = freq_at(ex)
    for _ in range(2):
        meas = acc_f @ d
        clock = estimate_clock(cmd_t, cmd_a, meas, fs, fa)
        cmd = np.interp(clock.cmd_time(tau), cmd_t, cmd_a, left=0.0, right=0.0)
        hs = [h1_sets(cmd, acc_f[:, k], fs, nperseg=nperseg, n_sets=1) for k in range(acc_f.shape[1])]
        f = hs[0].freq_hz
        low = (f >= ex.freq_start_hz) & (f <= ex.freq_start_hz + DIRECTION_BAND_HZ)
        w = hs[0].sxx[low]
        d_new = np.array([np.sum(w * h.h[low].real) / np.sum(w) for h in hs])
        if not np.all(np.isfinite(d_new)) or np.linalg.norm(d_new) == 0:
            break
        d = d_new / np.linalg.norm(d_new)
    meas = acc_f @ d
    clock = estimate_clock(cmd_t, cmd_a, meas, fs, fa)
    cmd = np.interp(clock.cmd_time(tau), cmd_t, cmd_a, left=0.0, right=0.0)
    return clock, cmd, meas, d, cmd_t, cmd_a


def analyse_raw(t_s, acc, excitation: Excitation | None = None, n_modes: int = 2,
                n_sets: int = 4, nperseg: int | None = None) -> RawResult:
    """Identify one raw recording ``(t_s (K,), acc (K,3) mm/s^2)``.

    ``excitation`` None: detect the generator (see module docstring) and use its defaults.
    """
    warnings: list[str] = []
    if len(t_s) < 100:
        raise ProfileError(f"raw recording: only {len(t_s)} samples; record the whole "
                           f"resonance test (about 130 s)")
    warnings += check_clipping(acc)
    fs, acc_u = resample_uniform(t_s, acc)
    sos = signal.butter(2, [3.0, 0.45 * fs], btype="bandpass", fs=fs, output="sos")
    acc_f = signal.sosfiltfilt(sos, acc_u - acc_u.mean(0), axis=0)
    if nperseg is None:
        nperseg = int(2 ** np.round(np.log2(1.3 * fs)))  # ~1.3 s windows
    if len(acc_f) < 4 * nperseg:
        raise ProfileError(f"raw recording too short: {len(acc_f) / fs:.1f} s; record the whole "
                           f"resonance test (about 130 s)")
    scores = {}
    if excitation is None:
        # both generators sweep the same chirp; the current one adds a slow +-400 mm/s^2
        # square wave of period 1.2 s, whose fundamental is looked for in the recording
        clock, cmd, meas, direction, *_ = _align(GENERATORS["legacy"], acc_f, fs, nperseg)
        ratio = sweep_ratio(acc_u @ direction, fs, GENERATORS["current"])
        scores["sweep_ratio"] = round(ratio, 3)
        excitation = GENERATORS["current" if ratio > SWEEP_DETECT else "legacy"]
        scores["detected"] = excitation.generator
    ex = excitation
    clock, cmd, meas, direction, cmd_t, cmd_a = _align(ex, acc_f, fs, nperseg)
    # The lag of a window's correlation peak is the clock error plus the plant's group delay
    # at the frequency being swept (1/(zeta*wn) at a mode: ~50 ms for 40 Hz, zeta 0.08), and
    # a near-periodic chirp makes whole-period slips easy. So align the *predicted response*
    # instead: fit, filter the command through the fitted model, re-estimate the clock; twice.
    tau = np.arange(len(meas)) / fs
    for _ in range(2):
        est = h1_sets(cmd, meas, fs, nperseg=nperseg, n_sets=1)
        f = est.freq_hz
        b0 = (f >= ex.freq_start_hz) & (f <= min(ex.freq_end_hz, 0.45 * fs))
        fit0 = fit_modes_magnitude(f[b0], np.abs(est.h[b0]), n_modes, weight=est.coherence[b0])
        pred = model_filter(fit0, cmd_a, 1.0 / (cmd_t[1] - cmd_t[0]))
        clock = estimate_clock(cmd_t, pred, meas, fs, freq_at(ex), clock=clock)
        cmd = np.interp(clock.cmd_time(tau), cmd_t, cmd_a, left=0.0, right=0.0)
    tau = np.arange(len(meas)) / fs
    # coverage: how much of the test the recording holds
    t_c = clock.cmd_time(tau)
    test_s = duration_s(ex)
    covered = float(np.clip(min(t_c[-1], test_s) - max(t_c[0], 0.0), 0.0, None))
    f_top = ex.freq_end_hz
    if covered < SHORT_FRACTION * test_s:
        f_top = min(ex.freq_end_hz, ex.freq_start_hz + ex.hz_per_sec * max(t_c[-1], 0.0))
        warnings.append(f"recording too short: it covers {covered:.1f} s of the {test_s:.1f} s "
                        f"test (up to about {f_top:.0f} Hz); record the whole TEST_RESONANCES run")
    if covered < 10.0:
        raise ProfileError(f"raw recording: only {covered:.1f} s overlap the resonance test; "
                           f"check --excitation/--freq-start/--hz-per-sec or record the whole test")
    est = h1_sets(cmd, meas, fs, nperseg=nperseg, n_sets=n_sets)
    f = est.freq_hz
    band = (f >= ex.freq_start_hz) & (f <= min(f_top, 0.45 * fs))
    w = est.coherence[band]
    fit = fit_modes_magnitude(f[band], np.abs(est.h[band]), n_modes, weight=w)
    set_fits = [fit_modes_magnitude(f[band], np.abs(hs[band]), n_modes, weight=w)
                for hs in est.h_sets]
    med = float(np.median(est.coherence[band]))
    if med < LOW_COHERENCE:
        warnings.append(f"low coherence: median {med:.2f} over {ex.freq_start_hz:.0f}-"
                        f"{f[band][-1]:.0f} Hz (< {LOW_COHERENCE}); the FRF is unreliable - check "
                        f"--excitation and that the sensor is on the moving part")
    for fn in fit.freq_hz:
        c = float(np.interp(fn, f, est.coherence))
        if c < LOW_COHERENCE and med >= LOW_COHERENCE:
            warnings.append(f"low coherence {c:.2f} at the {fn:.1f} Hz mode; its damping is "
                            f"uncertain")
    if not 0.7 <= fit.scale <= 1.4:
        warnings.append(f"|H| tends to {fit.scale:.2f} at low frequency, not 1 (a drive follows a "
                        f"slow command): the excitation amplitude is probably wrong; pass "
                        f"--accel-per-hz (legacy default 75, current 60)")
    return RawResult(ex, fs, direction, clock, est, band, fit, set_fits, warnings, scores)


def model_filter(fit, x, fs_hz: float):
    """``x`` (K,) at ``fs_hz`` through the fitted modes (bilinear, H(0) = dc + sum g)."""
    y = fit.dc * np.asarray(x, float)
    for fn, z, g in zip(fit.freq_hz, fit.damping, fit.gain):
        wn = 2 * np.pi * fn
        b, a = signal.bilinear([g * wn**2], [1.0, 2 * z * wn, wn**2], fs_hz)
        y = y + signal.lfilter(b, a, x)
    return y


def frf_rows(res: RawResult, grid_hz) -> np.ndarray:
    """(n_sets, len(grid_hz)) complex rows: the minimum-phase modal model fitted to each
    interleaved subset's |H1| (H(0) = 1)."""
    return np.array([sf.response(grid_hz) for sf in res.set_fits])
