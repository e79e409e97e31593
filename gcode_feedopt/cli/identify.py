"""``gcode-feedopt identify`` — a machine profile from measurements a user can make.

Supported: Klipper resonance spectra (``freq,psd_x,...``; magnitude only), FRF CSVs
(``freq_hz,real,imag``), UFF dataset 58, and Klipper raw accelerometer recordings
(``#time,accel_x,accel_y,accel_z``) with the known excitation of Klipper's resonance test
(``identify/raw.py``). The file kind is recognised from its header. Warnings (poor fit, low
coherence, clipping, short record) go to stderr, one line each, and into the axis provenance.
"""

from __future__ import annotations

import dataclasses
import pathlib

import click
import numpy as np

from ..errors import ProfileError
from ..identify.modal import fit_modes_complex
from ..identify.excitation import GENERATORS
from ..identify.raw import analyse_raw, frf_rows
from ..identify.readers import detect_kind, read_frf, read_raw, read_spectra, read_uff58
from ..identify.spectra import BAND_HZ, FREQ_SPREAD, GRID_HZ, ZETA_SPREAD, fit_spectrum, widened_frf_set
from ..inputs import check_input
from ..outputs import check_outputs, output_path
from ..pipeline import PLOT_SUFFIXES
from ..profile import load_profile, save_profile
from ..profile.io import check_profile_output
from ..profile.schema import AxisModel, FRFSet, Mode
from .options import Bounded, profile_files

#: a fit whose log-magnitude RMS residual exceeds this is flagged as poor
POOR_FIT_RMS = 0.5


def _raw_file(f, n_modes, excitation, n_sets):
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


def _identify_axis(axis: str, files, n_modes: int, excitation=None, n_sets: int = 4):
    rows, labels, fits, kinds, curves, warnings, raw_prov = [], [], [], [], [], [], []
    for f in files:
        kind = detect_kind(f)
        kinds.append(kind)
        if kind == "raw":
            fit, r, lab, curve, prov, warn = _raw_file(f, n_modes, excitation, n_sets)
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


@click.command("identify")
@click.option("--x", "x_files", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="measurement file of the X axis (repeat for several)")
@click.option("--y", "y_files", multiple=True, type=click.Path(exists=True, dir_okay=False),
              help="measurement file of the Y axis (repeat for several)")
@click.option("--base", default="ender3pro", show_default=True,
              help="profile whose limits and firmware settings are kept")
@click.option("--modes", "n_modes", type=click.IntRange(1, 3), default=2, show_default=True,
              help="number of modes fitted per axis")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False))
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), default=None,
              help="write a PNG of the fitted |H| against the data")
@click.option("--excitation", type=click.Choice(["auto", "legacy", "current"]), default="auto",
              show_default=True, help="Klipper resonance-test generator behind raw recordings "
              "(legacy: v0.12 and earlier; current: v0.13+); auto detects it from the data")
@click.option("--freq-start", type=Bounded("freq_hz"), default=None,
              help="raw: FREQ_START of the test, Hz")
@click.option("--freq-end", type=Bounded("freq_hz"), default=None,
              help="raw: FREQ_END of the test, Hz")
@click.option("--hz-per-sec", type=Bounded("hz_per_sec"), default=None,
              help="raw: HZ_PER_SEC of the test")
@click.option("--accel-per-hz", type=Bounded("accel_per_hz"), default=None,
              help="raw: ACCEL_PER_HZ, mm/s^2 per Hz")
@click.option("--sweeping-accel", type=Bounded("sweeping_accel"), default=None,
              help="raw, current generator: SWEEPING_ACCEL, mm/s^2")
@click.option("--sweeping-period", type=Bounded("sweeping_period"), default=None,
              help="raw, current generator: SWEEPING_PERIOD, s (0 = no sweeping)")
@click.option("--segments", type=click.IntRange(2, 16), default=4, show_default=True,
              help="raw: FRFs per recording (interleaved window subsets, the spread)")
def identify(x_files, y_files, base, n_modes, output, plot_path, excitation, freq_start,
             freq_end, hz_per_sec, accel_per_hz, sweeping_accel, sweeping_period, segments):
    """Build a profile from FRF files, Klipper spectra or Klipper raw recordings.

    \b
    gcode-feedopt identify --x resonances_x.csv --y resonances_y.csv -o mine.yaml
    gcode-feedopt identify --x raw_data_x.csv --y raw_data_y.csv -o mine.yaml --plot fit.png
    """
    if not x_files and not y_files:
        raise click.UsageError("give at least one --x or --y file")
    overrides = dict(freq_start_hz=freq_start, freq_end_hz=freq_end, hz_per_sec=hz_per_sec,
                     accel_per_hz=accel_per_hz, sweeping_accel_mm_s2=sweeping_accel,
                     sweeping_period_s=sweeping_period)
    if freq_start is not None and freq_end is not None and freq_end < freq_start:
        raise click.BadParameter(f"{freq_end:g} Hz is below --freq-start {freq_start:g} Hz; "
                                 "give FREQ_END >= FREQ_START", param_hint="'--freq-end'")
    ex = None
    if excitation != "auto":
        ex = GENERATORS[excitation].with_overrides(**overrides)
    elif any(v is not None for v in overrides.values()):
        raise click.UsageError("--freq-start/--freq-end/--hz-per-sec/--accel-per-hz/--sweeping-* "
                               "need --excitation legacy or current")
    base_p = load_profile(base)
    inputs = [*x_files, *y_files, *profile_files(base)]
    for f in inputs:
        check_input(f)
    check_profile_output(output, "-o", inputs)
    plot_t = check_outputs({"-o": output, "--plot": plot_path}, inputs=inputs,
                           suffixes={"-o": (".yaml", ".yml"), "--plot": PLOT_SUFFIXES}).get("--plot")
    axes = dict(base_p.axes)
    panels = {}
    for axis, files in (("x", x_files), ("y", y_files)):
        if files:
            axes[axis], panels[axis], warns = _identify_axis(axis, files, n_modes, ex, segments)
            for w in warns:
                click.echo(f"warning: {w}", err=True)
            m = ", ".join(f"{md.freq_hz:.1f} Hz zeta {md.damping:.3f}" for md in axes[axis].modes)
            click.echo(f"{axis}: {m}")
    prov = dict(base_p.provenance)
    prov["identified_from"] = {"x": list(x_files), "y": list(y_files), "base": base}
    twin = dataclasses.replace(base_p.twin, priors={})
    out = pathlib.Path(output)
    new = dataclasses.replace(base_p, name=out.stem, axes=axes, provenance=prov, twin=twin,
                              source_path=None)
    save_profile(new, out)
    click.echo(f"wrote {out}")
    if plot_path:
        from ..identify.identify_plot import plot_fits

        with output_path(plot_t) as tmp:
            plot_fits(tmp, panels)
        click.echo(f"wrote {plot_path}")
