"""FRF measurement files: CSV ``freq_hz,real,imag``, one file per measurement.

Commanded -> actual position, dimensionless (a stepper machine has unit DC gain). No YAML here,
so the identification and CLI layers can read FRF files without the profile format.
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..errors import ProfileError
from ..inputs import read_text
from ..outputs import output_file
from .schema import FRFSet

FRF_HEADER = "freq_hz,real,imag"
#: largest |value| in an FRF file (Hz or dimensionless gain): 1e308 passed the finite check
#: and overflowed the modal fit
MAX_ABS = 1e6


def read_frf_csv(path: pathlib.Path) -> tuple[np.ndarray, np.ndarray]:
    """Read one FRF file: header ``freq_hz,real,imag``. Returns (freq_hz (K,), H (K,) complex)."""
    path = pathlib.Path(path)
    if not path.exists():
        raise ProfileError(f"{path}: FRF file not found; check the path in the profile "
                           "(paths are relative to the YAML file)")
    text = read_text(path, "an FRF CSV (freq_hz,real,imag)", ProfileError)
    lines = text.splitlines()
    if not lines or lines[0].strip().replace(" ", "") != FRF_HEADER:
        raise ProfileError(f"{path}:1: FRF file must start with the header '{FRF_HEADER}', got "
                           f"{lines[0][:40]!r}" if lines else f"{path}: FRF file is empty")
    try:
        arr = np.loadtxt(lines[1:], delimiter=",", ndmin=2)
    except ValueError as exc:
        raise ProfileError(f"{path}: FRF rows must be three numbers each ({exc})") from None
    if arr.shape[1] != 3 or arr.shape[0] < 4:
        raise ProfileError(f"{path}: FRF needs at least 4 rows of freq_hz,real,imag; got "
                           f"{arr.shape[0]} rows of {arr.shape[1]} columns")
    f = arr[:, 0]
    if not np.all(np.isfinite(arr)):
        row = int(np.argwhere(~np.isfinite(arr))[0, 0]) + 2
        raise ProfileError(f"{path}:{row}: FRF contains a non-finite value; fix or drop the row")
    big = np.abs(arr) > MAX_ABS
    if big.any():
        row = int(np.argwhere(big)[0, 0]) + 2
        raise ProfileError(f"{path}:{row}: value beyond ±{MAX_ABS:g} (a position FRF is about 1, "
                           "frequencies a few hundred Hz); check the units or fix the row")
    if np.any(np.diff(f) <= 0) or f[0] < 0:
        raise ProfileError(f"{path}: freq_hz must be non-negative and strictly increasing")
    return f, arr[:, 1] + 1j * arr[:, 2]


def write_frf_csv(path: pathlib.Path, freq_hz: np.ndarray, response: np.ndarray) -> None:
    """Write one FRF file, 12 significant digits (a round trip is exact to 1e-12 relative)."""
    rows = np.column_stack([freq_hz, response.real, response.imag])
    with output_file(path, text=True) as fh:
        fh.write(FRF_HEADER + "\n")
        for r in rows:
            fh.write(f"{float(r[0]):.12g},{float(r[1]):.12g},{float(r[2]):.12g}\n")


def frf_set_from_files(paths, origin: str = "") -> FRFSet:
    """Stack FRF files measured on one grid into an FRFSet."""
    freqs, resp, labels = None, [], []
    for p in paths:
        p = pathlib.Path(p)
        f, h = read_frf_csv(p)
        if freqs is None:
            freqs = f
        elif f.shape != freqs.shape or np.max(np.abs(f - freqs)) > 1e-9 * max(1.0, freqs[-1]):
            raise ProfileError(f"{p}: frequency grid differs from {labels[0]}; all FRFs of an "
                               "axis must share one grid (resample them first)")
        resp.append(h)
        labels.append(p.name)
    if freqs is None:
        raise ProfileError(f"{origin}: no FRF files given")
    return FRFSet(freq_hz=freqs, response=np.vstack(resp), labels=tuple(labels))
