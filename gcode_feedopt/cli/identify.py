"""``gcode-feedopt identify`` — a machine profile from measurements a user can make.

Supported now: Klipper resonance spectra (``freq,psd_x,...``; magnitude only), FRF CSVs
(``freq_hz,real,imag``) and UFF dataset 58. The file kind is recognised from its header.
"""

from __future__ import annotations

import dataclasses
import pathlib

import click
import numpy as np

from ..errors import ProfileError
from ..identify.modal import fit_modes_complex
from ..identify.readers import detect_kind, read_frf, read_spectra, read_uff58
from ..identify.spectra import BAND_HZ, FREQ_SPREAD, GRID_HZ, ZETA_SPREAD, fit_spectrum, widened_frf_set
from ..profile import load_profile, save_profile
from ..profile.schema import AxisModel, FRFSet, Mode

#: a fit whose log-magnitude RMS residual exceeds this is flagged as poor
POOR_FIT_RMS = 0.5


def _identify_axis(axis: str, files, n_modes: int):
    rows, labels, fits, kinds, curves = [], [], [], [], []
    for f in files:
        kind = detect_kind(f)
        kinds.append(kind)
        if kind == "spectra":
            freq, psd = read_spectra(f, axis)
            fit = fit_spectrum(freq, psd, n_modes=n_modes)
            m = (freq >= BAND_HZ[0]) & (freq <= BAND_HZ[1]) & (psd > 0)
            curves.append((pathlib.Path(f).name, freq[m], np.sqrt(psd[m]) / freq[m] / fit.scale,
                           np.abs(fit.response(freq[m]))))
            rows.extend(widened_frf_set(fit))
            labels.extend(f"{pathlib.Path(f).name}:{v}" for v in
                          ("nominal", "f+", "f-", "zeta+", "zeta-"))
            if fit.rms_residual > POOR_FIT_RMS:
                click.echo(f"warning: {f}: poor fit (log-magnitude RMS residual "
                           f"{fit.rms_residual:.2f} > {POOR_FIT_RMS}); check the data", err=True)
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
    if "spectra" in kinds:
        prov["phase"] = (f"minimum-phase modal model; FRF set widened by f x (1 +/- {FREQ_SPREAD})"
                         f" and damping x (1 +/- {ZETA_SPREAD})")
    return AxisModel(frf=FRFSet(GRID_HZ, np.array(rows), tuple(labels)), modes=modes,
                     provenance=prov), curves


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
def identify(x_files, y_files, base, n_modes, output, plot_path):
    """Build a profile from FRF CSVs or Klipper resonance spectra.

    \b
    gcode-feedopt identify --x resonances_x.csv --y resonances_y.csv -o mine.yaml
    """
    if not x_files and not y_files:
        raise click.UsageError("give at least one --x or --y file")
    base_p = load_profile(base)
    axes = dict(base_p.axes)
    panels = {}
    for axis, files in (("x", x_files), ("y", y_files)):
        if files:
            axes[axis], panels[axis] = _identify_axis(axis, files, n_modes)
            m = ", ".join(f"{md.freq_hz:.1f} Hz zeta {md.damping:.3f}" for md in axes[axis].modes)
            click.echo(f"{axis}: {m}")
    prov = dict(base_p.provenance)
    prov["identified_from"] = {"x": list(x_files), "y": list(y_files), "base": base}
    twin = dataclasses.replace(base_p.twin, priors={})
    out = pathlib.Path(output)
    new = dataclasses.replace(base_p, name=out.stem, axes=axes, provenance=prov, twin=twin,
                              source_path=None)
    try:
        save_profile(new, out)
    except OSError as exc:
        raise ProfileError(f"{out}: cannot write ({exc.strerror})") from None
    click.echo(f"wrote {out}")
    if plot_path:
        from ..identify.identify_plot import plot_fits

        plot_fits(plot_path, panels)
        click.echo(f"wrote {plot_path}")
