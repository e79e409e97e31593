"""Identification: machine-profile modes and FRFs from measurements a user can make.

modal.py — pure modal fitting of complex or magnitude-only frequency responses;
spectra.py — Klipper resonance spectra; excitation.py — Klipper's resonance-test command
(legacy and current generator); h1.py — clock alignment and H1 with coherence; raw.py —
raw accelerometer recordings end to end; readers.py — the only module that opens files;
axis.py — one axis's AxisModel (FRF set, modes, provenance) from its files, for ``identify``.
"""

from .modal import ModalFit, fit_modes_complex, fit_modes_magnitude, modal_response

__all__ = ["ModalFit", "fit_modes_complex", "fit_modes_magnitude", "modal_response"]
