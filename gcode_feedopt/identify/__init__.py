"""Identification: machine-profile modes and FRFs from measurements a user can make.

modal.py — pure modal fitting of complex or magnitude-only frequency responses.
"""

from .modal import ModalFit, fit_modes_complex, fit_modes_magnitude, modal_response

__all__ = ["ModalFit", "fit_modes_complex", "fit_modes_magnitude", "modal_response"]
