"""Modal fitting of frequency responses (pure numerics: arrays in, frozen dataclass out).

Model, commanded -> actual position (dimensionless, minimum phase for positive gains):

    H(f) = d + sum_i g_i * wn_i^2 / (wn_i^2 - w^2 + 2j*zeta_i*wn_i*w),   w = 2*pi*f

with ``d`` the residual DC term, so H(0) = d + sum g_i (1 for a rigid drive). The initial
guess comes from peak picking on |H| (half-power bandwidth gives the damping); the
parameters are then refined with ``scipy.optimize.least_squares`` on the real and imaginary
parts (complex data) or on log|H| (magnitude-only data, e.g. the square root of a Klipper
power spectral density divided by the excitation spectrum).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import find_peaks

from ..errors import ProfileError

#: damping ratio bounds for the fit (printer/CNC axes lie far inside)
ZETA_MIN, ZETA_MAX = 0.002, 0.8


@dataclass(frozen=True)
class ModalFit:
    """Fitted modes of one axis.

    Attributes:
        freq_hz: (M,) natural frequencies, Hz, ascending.
        damping: (M,) damping ratios.
        gain: (M,) modal gains (dimensionless).
        dc: residual DC term d.
        scale: magnitude scale fitted for magnitude-only data (1 for complex data).
        rms_residual: RMS of the fit residual (relative units of the fitted quantity).
    """

    freq_hz: np.ndarray
    damping: np.ndarray
    gain: np.ndarray
    dc: float
    scale: float
    rms_residual: float

    def response(self, freq_hz: np.ndarray) -> np.ndarray:
        """Complex model response at ``freq_hz`` (K,) -> (K,), without ``scale``."""
        return modal_response(freq_hz, self.freq_hz, self.damping, self.gain, self.dc)


def modal_response(freq_hz, fn_hz, zeta, gain, dc=0.0) -> np.ndarray:
    """Sum of second-order modes plus a DC term at ``freq_hz`` (K,); returns (K,) complex."""
    w = 2 * np.pi * np.asarray(freq_hz, float)[:, None]
    wn = 2 * np.pi * np.atleast_1d(np.asarray(fn_hz, float))[None, :]
    z = np.atleast_1d(np.asarray(zeta, float))[None, :]
    g = np.atleast_1d(np.asarray(gain, float))[None, :]
    return dc + np.sum(g * wn**2 / (wn**2 - w**2 + 2j * z * wn * w), axis=1)


def _half_power_zeta(freq_hz, mag, k) -> float:
    """Damping from the half-power bandwidth around peak index k (fallback 0.05)."""
    level = mag[k] / np.sqrt(2)
    lo = k
    while lo > 0 and mag[lo] > level:
        lo -= 1
    hi = k
    while hi < len(mag) - 1 and mag[hi] > level:
        hi += 1
    if lo == k or hi == k or mag[lo] > level or mag[hi] > level:
        return 0.05
    # linear interpolation of the crossing frequencies
    f_lo = np.interp(level, [mag[lo], mag[lo + 1]], [freq_hz[lo], freq_hz[lo + 1]])
    f_hi = np.interp(level, [mag[hi], mag[hi - 1]], [freq_hz[hi], freq_hz[hi - 1]])
    return float(np.clip((f_hi - f_lo) / (2 * freq_hz[k]), 0.01, 0.5))


def initial_guess(freq_hz, mag, n_modes: int) -> tuple[np.ndarray, np.ndarray]:
    """Peak picking: the ``n_modes`` most prominent peaks of ``mag`` -> (fn_hz, zeta)."""
    peaks, props = find_peaks(mag, prominence=0)
    if len(peaks) == 0:
        peaks = np.array([int(np.argmax(mag))])
        prom = np.array([1.0])
    else:
        prom = props["prominences"]
    order = np.argsort(prom)[::-1][:n_modes]
    ks = np.sort(peaks[order])
    fn = [float(freq_hz[k]) for k in ks]
    zeta = [_half_power_zeta(freq_hz, mag, k) for k in ks]
    # fewer peaks than modes asked: spread the rest above the last one
    while len(fn) < n_modes:
        fn.append(fn[-1] * 1.5)
        zeta.append(0.1)
    return np.array(fn), np.array(zeta)


def _check(freq_hz, data, n_modes):
    freq_hz = np.asarray(freq_hz, float)
    if freq_hz.ndim != 1 or len(freq_hz) != len(data) or len(freq_hz) < 4 * n_modes + 2:
        raise ProfileError(f"modal fit: need at least {4 * n_modes + 2} frequency points of "
                           f"matching length, got {len(freq_hz)} frequencies and {len(data)} "
                           f"values; measure a wider band or fit fewer modes")
    if not 1 <= n_modes <= 3:
        raise ProfileError(f"modal fit: n_modes={n_modes} outside 1..3; fit 1, 2 or 3 modes")
    return freq_hz


def _unpack(p, m):
    return np.exp(p[:m]), np.exp(p[m:2 * m]), p[2 * m:3 * m], p[3 * m]


def fit_modes_complex(freq_hz, response, n_modes: int = 1, weight=None,
                      max_delay_s: float = 0.0) -> ModalFit:
    """Fit ``n_modes`` modes + DC to a complex FRF ``response`` (K,) at ``freq_hz`` (K,).

    ``weight`` (K,) optional (e.g. coherence). Residuals are relative to max|H| so the
    fit is scale free. ``max_delay_s`` > 0 also fits a pure delay |tau| <= max_delay_s
    (H_data = H_modal * exp(-j w tau)), absorbing a residual alignment error of a few
    samples; the delay is not part of the returned modes. Returns a ModalFit with scale 1.
    """
    response = np.asarray(response, complex)
    freq_hz = _check(freq_hz, response, n_modes)
    w = np.ones_like(freq_hz) if weight is None else np.asarray(weight, float)
    ok = freq_hz > 0
    f, h, w = freq_hz[ok], response[ok], w[ok]
    mag = np.abs(h)
    fn0, z0 = initial_guess(f, mag, n_modes)
    # gain guess: peak magnitude of a single mode is g/(2 zeta); share the DC value
    dc_level = float(np.abs(h[0]).real)
    g0 = np.array([dc_level / n_modes] * n_modes)
    scale = float(np.max(mag))
    best = None
    for zmul in (1.0, 0.5, 2.0):
        p0 = np.concatenate([np.log(fn0), np.log(np.clip(z0 * zmul, ZETA_MIN * 1.01, ZETA_MAX * 0.99)),
                             g0, [0.0, 0.0]])
        dmax = max(max_delay_s, 1e-6)  # a non-empty box; 1 us is negligible
        lo = np.concatenate([np.log(np.full(n_modes, f[0] * 0.5)), np.full(n_modes, np.log(ZETA_MIN)),
                             np.full(n_modes, -np.inf), [-np.inf, -dmax]])
        hi = np.concatenate([np.log(np.full(n_modes, f[-1] * 2)), np.full(n_modes, np.log(ZETA_MAX)),
                             np.full(n_modes, np.inf), [np.inf, dmax]])

        def resid(p):
            fn, z, g, d = _unpack(p, n_modes)
            rot = np.exp(-2j * np.pi * f * p[-1])
            e = (modal_response(f, fn, z, g, d) * rot - h) * w / scale
            return np.concatenate([e.real, e.imag])

        sol = least_squares(resid, np.clip(p0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi),
                            x_scale="jac", max_nfev=2000)
        if best is None or sol.cost < best.cost:
            best = sol
    fn, z, g, d = _unpack(best.x, n_modes)
    order = np.argsort(fn)
    rms = float(np.sqrt(np.mean(best.fun**2)))
    return ModalFit(fn[order], z[order], g[order], float(d), 1.0, rms)


def fit_modes_magnitude(freq_hz, magnitude, n_modes: int = 1, weight=None,
                        fixed_dc: float | None = None) -> ModalFit:
    """Fit ``n_modes`` modes to a magnitude-only response ``magnitude`` (K,) >= 0.

    The model is ``scale * |H(f)|`` with H normalised to H(0) = 1 (gains sum to 1 - dc),
    fitted on log magnitude (so a PSD's dynamic range does not let the peak swamp the
    rest). Magnitude alone leaves the sign of the phase free; the returned modes give the
    minimum-phase response (positive gains), which is what a passive drive has.
    """
    mag = np.asarray(magnitude, float)
    freq_hz = _check(freq_hz, mag, n_modes)
    w = np.ones_like(freq_hz) if weight is None else np.asarray(weight, float)
    ok = (freq_hz > 0) & (mag > 0) & np.isfinite(mag)
    f, a, w = freq_hz[ok], mag[ok], w[ok]
    if len(f) < 4 * n_modes + 2:
        raise ProfileError(f"modal fit: only {len(f)} positive magnitude values; "
                           f"need {4 * n_modes + 2}")
    fn0, z0 = initial_guess(f, a, n_modes)
    dc = 0.0 if fixed_dc is None else fixed_dc
    # gain shares: log-parametrised and normalised so sum(g) = 1 - dc
    best = None
    for zmul in (1.0, 0.5, 2.0):
        z_init = np.clip(z0 * zmul, ZETA_MIN * 1.01, ZETA_MAX * 0.99)
        h0 = np.abs(modal_response(f, fn0, z_init, np.full(n_modes, (1 - dc) / n_modes), dc))
        ls0 = float(np.median(np.log(a) - np.log(h0)))
        p0 = np.concatenate([np.log(fn0), np.log(z_init), np.zeros(n_modes), [ls0]])
        lo = np.concatenate([np.log(np.full(n_modes, f[0] * 0.5)), np.full(n_modes, np.log(ZETA_MIN)),
                             np.full(n_modes, -5.0), [-np.inf]])
        hi = np.concatenate([np.log(np.full(n_modes, f[-1] * 2)), np.full(n_modes, np.log(ZETA_MAX)),
                             np.full(n_modes, 5.0), [np.inf]])

        def model(p):
            fn, z = np.exp(p[:n_modes]), np.exp(p[n_modes:2 * n_modes])
            s = np.exp(p[2 * n_modes:3 * n_modes])
            g = (1 - dc) * s / s.sum()
            return fn, z, g, p[-1]

        def resid(p):
            fn, z, g, ls = model(p)
            hm = np.abs(modal_response(f, fn, z, g, dc))
            return (np.log(hm + 1e-300) + ls - np.log(a)) * w

        sol = least_squares(resid, np.clip(p0, lo + 1e-9, hi - 1e-9), bounds=(lo, hi),
                            x_scale="jac", max_nfev=3000)
        if best is None or sol.cost < best[0].cost:
            best = (sol, model(sol.x))
    sol, (fn, z, g, ls) = best
    order = np.argsort(fn)
    rms = float(np.sqrt(np.mean(sol.fun**2)))
    return ModalFit(fn[order], z[order], g[order], float(dc), float(np.exp(ls)), rms)
