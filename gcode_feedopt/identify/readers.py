"""File-kind detection and readers (the only identify module that opens files).

Kinds, recognised from the header line:
- ``frf``: CSV ``freq_hz,real,imag`` (complex FRF, commanded -> actual position);
- ``spectra``: Klipper resonance spectra ``freq,psd_x,psd_y,psd_z,psd_xyz``;
- ``uff``: Universal File Format, dataset 58 (function records), read with pyuff;
- ``raw``: Klipper raw accelerometer recording ``#time,accel_x,accel_y,accel_z`` (s, mm/s^2).
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..errors import ProfileError
from ..inputs import read_text


def detect_kind(path) -> str:
    """'frf', 'spectra', 'raw' or 'uff' from the first line of ``path``; ProfileError otherwise."""
    path = pathlib.Path(path)
    try:
        head = path.open("r", errors="replace").readline().strip().lower().replace(" ", "")
    except OSError as exc:
        raise ProfileError(f"{path}: cannot read ({exc.strerror}); check the path") from None
    if head == "-1":
        return "uff"
    if head.startswith("freq_hz,real,imag"):
        return "frf"
    if head.startswith("freq,psd_x"):
        return "spectra"
    if head.lstrip("#").startswith("time,accel_x,accel_y,accel_z"):
        return "raw"
    raise ProfileError(f"{path}:1: unknown file kind (header {head[:40]!r}); expected "
                       f"'freq_hz,real,imag' (FRF), 'freq,psd_x,...' (Klipper spectra), "
                       f"'#time,accel_x,accel_y,accel_z' (Klipper raw) or UFF ('    -1')")


#: largest |value| read from a measurement table (Hz, |H|, PSD, mm/s², s): 1e308 passed as
#: finite and overflowed the fits
MAX_ABS = 1e12


def _table(path, what: str, names=True):
    """A numeric CSV table, as text first (binary data or non-UTF-8 bytes: one-line error),
    every value finite and within ±MAX_ABS."""
    import io
    import warnings

    text = read_text(path, what, ProfileError)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty table: reported below
            data = np.genfromtxt(io.StringIO(text), delimiter=",", names=names,
                                 invalid_raise=True)
    except ValueError as exc:
        raise ProfileError(f"{path}: not {what} ({' '.join(str(exc).split())[:120]}); fix "
                           "the row or pass the file the tool wrote") from None
    cols = data.dtype.names or ()
    values = np.column_stack([np.asarray(data[c], float) for c in cols]) if cols else \
        np.asarray(data, float).reshape(len(np.atleast_1d(data)), -1)
    if values.size == 0 or values.shape[0] < 2:
        raise ProfileError(f"{path}: no data rows; pass {what} with its measurements")
    bad = ~np.isfinite(values) | (np.abs(values) > MAX_ABS)
    if bad.any():
        row = int(np.argwhere(bad)[0, 0]) + 2
        raise ProfileError(f"{path}:{row}: not a number, or beyond ±{MAX_ABS:g}; fix or drop "
                           "the row")
    return data


def read_spectra(path, axis: str) -> tuple[np.ndarray, np.ndarray]:
    """Klipper spectra file -> (freq_hz (K,), psd (K,)) of column ``psd_<axis>``."""
    data = _table(path, "a Klipper resonance spectrum (freq,psd_x,...)")
    col = f"psd_{axis}"
    if col not in data.dtype.names:
        raise ProfileError(f"{path}: no column {col!r} (have {data.dtype.names}); "
                           f"pass the file under --x or --y to match its test axis")
    return np.asarray(data["freq"], float), np.asarray(data[col], float)


def read_frf(path) -> tuple[np.ndarray, np.ndarray]:
    """FRF CSV -> (freq_hz (K,), response (K,) complex)."""
    data = _table(path, "an FRF CSV (freq_hz,real,imag)")
    return np.asarray(data["freq_hz"], float), data["real"] + 1j * data["imag"]


def read_uff58(path) -> list[tuple[np.ndarray, np.ndarray, str]]:
    """Every dataset-58 record of a UFF file -> [(freq_hz (K,), response (K,) complex, id)]."""
    import pyuff  # imported here: only this reader needs it

    try:
        sets = pyuff.UFF(str(path)).read_sets()
    except Exception as exc:  # pyuff raises bare Exceptions on malformed files
        raise ProfileError(f"{path}: not a readable UFF file ({exc}); export dataset 58") from None
    if isinstance(sets, dict):
        sets = [sets]
    out = [(np.asarray(s["x"], float), np.asarray(s["data"], complex), str(s.get("id1", "")))
           for s in sets if s.get("type") == 58]
    if not out:
        raise ProfileError(f"{path}: no dataset 58 (FRF) in the UFF file; export FRFs as 58")
    return out


def read_raw(path) -> tuple[np.ndarray, np.ndarray]:
    """Klipper raw accelerometer CSV -> (t_s (K,), accel_mm_s2 (K, 3))."""
    text = read_text(path, "a Klipper raw recording (#time,accel_x,accel_y,accel_z)",
                     ProfileError)
    try:
        data = np.loadtxt(text.splitlines(), delimiter=",", comments="#", ndmin=2)
    except ValueError as exc:
        raise ProfileError(f"{path}: not a numeric '#time,accel_x,accel_y,accel_z' table "
                           f"({' '.join(str(exc).split())[:120]}); pass the file Klipper "
                           "wrote") from None
    if data.shape[1] < 4 or len(data) < 2:
        raise ProfileError(f"{path}: need 4 columns time,accel_x,accel_y,accel_z and at least "
                           f"2 rows, got {data.shape[1]} columns, {len(data)} rows")
    bad = ~np.isfinite(data) | (np.abs(data) > MAX_ABS)
    if bad.any():
        row = int(np.argwhere(bad)[0, 0]) + 2
        raise ProfileError(f"{path}: row {row} of the data: not a number, or beyond "
                           f"±{MAX_ABS:g}; fix or drop the row")
    return data[:, 0], data[:, 1:4]
