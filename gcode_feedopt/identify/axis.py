"""One axis's model from its measurement files: the ``AxisModel`` ``gcode-feedopt identify``
writes into a profile (FRF set on ``spectra.GRID_HZ``, modes averaged over the files,
provenance and warnings). Files are read through ``readers``; nothing is written.
"""

from __future__ import annotations

import pathlib

import numpy as np

from ..errors import ProfileError
from ..profile.schema import AxisModel, FRFSet, Mode
from .modal import fit_modes_complex
from .raw import analyse_raw, frf_rows
from .readers import detect_kind, read_frf, read_raw, read_spectra, read_uff58
from .spectra import BAND_HZ, FREQ_SPREAD, GRID_HZ, ZETA_SPREAD, fit_spectrum, widened_frf_set

#: a fit whose log-magnitude RMS residual exceeds this is flagged as poor
POOR_FIT_RMS = 0.5


def raw_file_fit(f, n_modes, excitation, n_sets):
    """One raw recording -> (fit, rows, labels, curve, provenance entry, warnings)."""
    t, acc = read_raw(f)
    try:
        res = analyse_raw(t, acc, excitation=excitation, n_modes=n_modes, n_sets=n_sets)
    except ProfileError as exc:
        raise ProfileError(f"{f}: {exc}") from None
    name = pathlib.Path(f).name
    fq, band = res.h1.freq_hz, res.band
    curve = (name, fq[band], np.abs(res.h1.h[band]) / res.fit.scale, np.abs(res.fit.response(fq[band])))
    prov = {"file": str(f), "excitation": res.excitation.to_dict(),
            "detection": res.scores,
            "direction_sensor_xyz": [round(float(v), 4) for v in res.direction],
            "sample_rate_hz": round(res.fs_hz, 3),
            "offset_s": round(float(res.clock.offset_s), 5),
            "clock_rate_error": float(f"{res.clock.rate_error:.3e}"),
            "level": round(res.fit.scale, 3),
            "median_coherence": round(float(np.median(res.h1.coherence[band])), 3),
            "segments": len(res.set_fits),
            "segment_modes": [{"freq_hz": [round(float(v), 3) for v in sf.freq_hz],
                               "damping": [round(float(v), 4) for v in sf.damping]}
                              for sf in res.set_fits],
            "rows": (f"minimum-phase modal model fitted to |H1| of each of {len(res.set_fits)} "
                     f"interleaved window subsets over {fq[band][0]:.1f}-{fq[band][-1]:.1f} Hz "
                     f"(H1 phase not used: see docs/identification.md)")}
    warnings = [f"{f}: {w}" for w in res.warnings]
    labels = [f"{name}:segment{k + 1}" for k in range(len(res.set_fits))]
    return res.fit, frf_rows(res, GRID_HZ), labels, curve, prov, warnings


def identify_axis(axis: str, files, n_modes: int, excitation=None, n_sets: int = 4):
    """The ``AxisModel`` of one axis from its measurement files (any mix of the kinds
    ``readers.detect_kind`` recognises): FRF rows on ``spectra.GRID_HZ``, the modes averaged
    over the files, provenance. Returns ``(axis_model, curves, warnings)``; ``curves`` are
    (label, freq_hz, |data|, |fit|) for ``identify_plot.plot_fits``."""
    rows, labels, fits, kinds, curves, warnings, raw_prov = [], [], [], [], [], [], []
    for f in files:
        kind = detect_kind(f)
        kinds.append(kind)
        if kind == "raw":
            fit, r, lab, curve, prov, warn = raw_file_fit(f, n_modes, excitation, n_sets)
            fits.append(fit)
            rows.extend(r)
            labels.extend(lab)
            curves.append(curve)
            raw_prov.append(prov)
            warnings.extend(warn)
        elif kind == "spectra":
            freq, psd = read_spectra(f, axis)
            fit = fit_spectrum(freq, psd, n_modes=n_modes)
            m = (freq >= BAND_HZ[0]) & (freq <= BAND_HZ[1]) & (psd > 0)
            curves.append((pathlib.Path(f).name, freq[m], np.sqrt(psd[m]) / freq[m] / fit.scale,
                           np.abs(fit.response(freq[m]))))
            rows.extend(widened_frf_set(fit))
            labels.extend(f"{pathlib.Path(f).name}:{v}" for v in
                          ("nominal", "f+", "f-", "zeta+", "zeta-"))
            if fit.rms_residual > POOR_FIT_RMS:
                warnings.append(f"{f}: poor fit (log-magnitude RMS residual "
                                f"{fit.rms_residual:.2f} > {POOR_FIT_RMS}); check the data")
            fits.append(fit)
        else:
            records = read_uff58(f) if kind == "uff" else [(*read_frf(f), "")]
            for k, (freq, h, rid) in enumerate(records):
                fits.append(fit_modes_complex(freq, h, n_modes=n_modes))
                curves.append((f"{pathlib.Path(f).name}:{k + 1}", freq, np.abs(h),
                               np.abs(fits[-1].response(freq))))
                rows.append(np.interp(GRID_HZ, freq, h.real)
                            + 1j * np.interp(GRID_HZ, freq, h.imag))
                labels.append(f"{pathlib.Path(f).name}:{k + 1}" if kind == "uff"
                              else pathlib.Path(f).name)
    # modes of the axis: mean over the files
    fn = np.mean([ft.freq_hz for ft in fits], axis=0)
    zeta = np.mean([ft.damping for ft in fits], axis=0)
    gain = np.mean([ft.gain for ft in fits], axis=0)
    modes = tuple(Mode(float(a), float(b), float(c)) for a, b, c in zip(fn, zeta, gain))
    prov = {"kind": "identify:" + "+".join(sorted(set(kinds))),
            "files": [str(f) for f in files],
            "per_file_modes": [{"freq_hz": [round(float(v), 3) for v in ft.freq_hz],
                                "damping": [round(float(v), 4) for v in ft.damping]}
                               for ft in fits]}
    if raw_prov:
        prov["raw"] = raw_prov
    if warnings:
        prov["warnings"] = warnings
    if "spectra" in kinds:
        prov["phase"] = (f"minimum-phase modal model; FRF set widened by f x (1 +/- {FREQ_SPREAD})"
                         f" and damping x (1 +/- {ZETA_SPREAD})")
    return AxisModel(frf=FRFSet(GRID_HZ, np.array(rows), tuple(labels)), modes=modes,
                     provenance=prov), curves, warnings
