"""Modes and an FRF set from Klipper resonance spectra (magnitude only; pure numerics).

Klipper's legacy test commands an acceleration square wave of amplitude A*f while f rises
at a constant rate, so the excitation acceleration PSD is proportional to f^2 and the
measured acceleration PSD is proportional to |H(f)|^2 * f^2. Hence |H| ∝ sqrt(PSD)/f, fitted
with ``fit_modes_magnitude`` (free scale; H(0) = 1). The phase is that of the fitted
minimum-phase modal model. Because phase is inferred, not measured, the FRF set widens
the uncertainty: besides the nominal model it holds the model with each natural frequency
scaled by 1 ± FREQ_SPREAD and each damping ratio by 1 ± ZETA_SPREAD (documented spread, not
measured).
"""

from __future__ import annotations

import numpy as np

from .modal import ModalFit, fit_modes_magnitude

#: band of the Klipper test (legacy 5-133.33 Hz, current 5-135 Hz)
BAND_HZ = (5.0, 133.0)
#: relative spread applied to frequencies and damping for the widened FRF set
FREQ_SPREAD = 0.03
ZETA_SPREAD = 0.25
#: FRF grid written into the profile (same as the built-in profiles: 0..250 Hz, 0.5 Hz)
GRID_HZ = np.arange(0.0, 250.0 + 1e-9, 0.5)


def fit_spectrum(freq_hz, psd, n_modes: int = 2) -> ModalFit:
    """Fit modes to one PSD column (K,) at ``freq_hz`` (K,) within BAND_HZ."""
    m = (freq_hz >= BAND_HZ[0]) & (freq_hz <= BAND_HZ[1]) & (psd > 0)
    mag = np.sqrt(psd[m]) / freq_hz[m]
    return fit_modes_magnitude(freq_hz[m], mag, n_modes=n_modes)


def widened_frf_set(fit: ModalFit) -> np.ndarray:
    """(5, len(GRID_HZ)) complex responses: nominal, f ±FREQ_SPREAD, zeta ±ZETA_SPREAD."""
    rows = []
    for df, dz in ((1, 1), (1 + FREQ_SPREAD, 1), (1 - FREQ_SPREAD, 1),
                   (1, 1 + ZETA_SPREAD), (1, 1 - ZETA_SPREAD)):
        rows.append(fit.__class__(fit.freq_hz * df, fit.damping * dz, fit.gain, fit.dc,
                                  fit.scale, fit.rms_residual).response(GRID_HZ))
    return np.array(rows)
