"""File-kind detection and readers (the only identify module that opens files).

Kinds, recognised from the header line:
- ``frf``: CSV ``freq_hz,real,imag`` (complex FRF, commanded -> actual position);
- ``spectra``: Klipper resonance spectra ``freq,psd_x,psd_y,psd_z,psd_xyz``.
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..errors import ProfileError


def detect_kind(path) -> str:
    """'frf' or 'spectra' from the first line of ``path``; ProfileError otherwise."""
    path = pathlib.Path(path)
    try:
        head = path.open("r", errors="replace").readline().strip().lower().replace(" ", "")
    except OSError as exc:
        raise ProfileError(f"{path}: cannot read ({exc.strerror}); check the path") from None
    if head.startswith("freq_hz,real,imag"):
        return "frf"
    if head.startswith("freq,psd_x"):
        return "spectra"
    raise ProfileError(f"{path}:1: unknown file kind (header {head[:40]!r}); expected "
                       f"'freq_hz,real,imag' (FRF) or 'freq,psd_x,...' (Klipper spectra)")


def read_spectra(path, axis: str) -> tuple[np.ndarray, np.ndarray]:
    """Klipper spectra file -> (freq_hz (K,), psd (K,)) of column ``psd_<axis>``."""
    data = np.genfromtxt(path, delimiter=",", names=True)
    col = f"psd_{axis}"
    if col not in data.dtype.names:
        raise ProfileError(f"{path}: no column {col!r} (have {data.dtype.names}); "
                           f"pass the file under --x or --y to match its test axis")
    return np.asarray(data["freq"], float), np.asarray(data[col], float)


def read_frf(path) -> tuple[np.ndarray, np.ndarray]:
    """FRF CSV -> (freq_hz (K,), response (K,) complex)."""
    data = np.genfromtxt(path, delimiter=",", names=True)
    return np.asarray(data["freq_hz"], float), data["real"] + 1j * data["imag"]
