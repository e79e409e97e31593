"""FRF measurement files: CSV ``freq_hz,real,imag``, one file per measurement.

Commanded -> actual position, dimensionless (a stepper machine has unit DC gain). No YAML here,
so the identification and CLI layers can read FRF files without the profile format.
"""

from __future__ import annotations

import pathlib

import numpy as np
from scipy.interpolate import CubicSpline

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


def _resample(f: np.ndarray, h: np.ndarray, at: np.ndarray) -> np.ndarray:
    """One measured FRF at other frequencies inside its band: a cubic spline of H or of 1/H,
    whichever predicts the member's own odd-numbered samples from its even ones better.

    Not a chord: a peak of ζ 0.03 sampled every 2 Hz loses 20 % of its height to one (and the
    modal fit reads the flattened peak as two modes). Not a spline of H alone either: it still
    errs 23 % at such a peak, where 1/H — a quadratic in s near one mode — is smooth and the
    spline of it exact to the noise. Near an antiresonance the roles swap, so the member's own
    data choose (tests/profile/test_frf_io.py)."""
    forms = [(lambda v: v, lambda v: v)]
    if np.all(np.abs(h) > 1e-9 * np.max(np.abs(h))):
        forms.append((lambda v: 1.0 / v, lambda v: 1.0 / v))
    best, err_best = forms[0], np.inf
    if f.size >= 8:
        ev, od = slice(0, None, 2), slice(1, -1, 2)
        for fw, bw in forms:
            e = np.abs(bw(CubicSpline(f[ev], fw(h[ev]))(f[od])) - h[od]) / np.abs(h[od]).clip(1e-300)
            e = float(np.mean(np.square(e)))
            if e < err_best:
                best, err_best = (fw, bw), e
    fw, bw = best
    return bw(CubicSpline(f, fw(h))(at))


def frf_set_from_files(paths, origin: str = "", notes: list | None = None) -> FRFSet:
    """Stack FRF files of one axis into an FRFSet.

    Measurements on different grids (a stepped sine re-planned between runs, a swept sine
    beside a stepped one) are put on one: the band all of them cover, on the grid of the member
    with the most frequencies there, the others interpolated (``_resample``).
    One sentence saying so is appended to ``notes`` (``profile build`` shows it). Members that
    share no band are refused."""
    grids, resp, labels = [], [], []
    for p in paths:
        p = pathlib.Path(p)
        f, h = read_frf_csv(p)
        grids.append(f)
        resp.append(h)
        labels.append(p.name)
    if not grids:
        raise ProfileError(f"{origin}: no FRF files given")
    freqs = grids[0]
    same = all(g.shape == freqs.shape and np.max(np.abs(g - freqs)) <= 1e-9 * max(1.0, freqs[-1])
               for g in grids[1:])
    if not same:
        lo = max(float(g[0]) for g in grids)
        hi = min(float(g[-1]) for g in grids)
        inside = [(g >= lo - 1e-9) & (g <= hi + 1e-9) for g in grids]
        ref = int(np.argmax([int(m.sum()) for m in inside]))
        freqs = grids[ref][inside[ref]]
        if hi <= lo or freqs.size < 4:
            first = int(np.argmax([g[0] for g in grids]))
            last = int(np.argmin([g[-1] for g in grids]))
            raise ProfileError(f"{paths[first]}: its band ({grids[first][0]:g}–{grids[first][-1]:g} Hz) "
                               f"and that of {labels[last]} ({grids[last][0]:g}–{grids[last][-1]:g} Hz) "
                               "share fewer than 4 frequencies; measure every FRF of an axis over "
                               "one band")
        resp = [h[inside[ref]] if k == ref else _resample(g, h, freqs)
                for k, (g, h) in enumerate(zip(grids, resp))]
        if notes is not None:
            notes.append(f"{len(grids)} FRFs on different frequency grids: put on {labels[ref]}'s "
                         f"grid over the band all cover, {freqs[0]:g}–{freqs[-1]:g} Hz "
                         f"({freqs.size} frequencies), the others interpolated")
    return FRFSet(freq_hz=freqs, response=np.vstack(resp), labels=tuple(labels))
