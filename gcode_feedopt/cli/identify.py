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

from ..identify.axis import identify_axis
from ..identify.excitation import GENERATORS
from ..identify.identify_plot import plot_fits
from ..inputs import check_input
from ..outputs import check_outputs, output_path
from ..pipeline import PLOT_SUFFIXES
from ..profile import load_profile, save_profile
from ..profile.io import check_profile_output
from ..profile.klipper_cfg import read_input_shaper
from .options import Bounded, profile_files


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
@click.option("--flavour", type=click.Choice(["marlin", "klipper"]), default=None,
              help="the machine's firmware, if not the base profile's (its planner model: "
                   "junctions, accelerations, the commands that set limits; docs/firmware.md)")
@click.option("--klipper-config", "klipper_cfg", type=click.Path(exists=True, dir_okay=False),
              default=None, help="the printer.cfg whose [input_shaper] the printer prints with: "
              "stated in the profile (firmware.input_shaper); measure with it off, as "
              "TEST_RESONANCES does")
@click.option("--name", default=None, help="the new profile's name  [the output file's stem]")
@click.option("--description", default=None,
              help="its description  [identified from the files on BASE's limits]")
def identify(x_files, y_files, base, n_modes, output, plot_path, excitation, freq_start,
             freq_end, hz_per_sec, accel_per_hz, sweeping_accel, sweeping_period, segments,
             flavour, klipper_cfg, name, description):
    """Build a profile from FRF files, Klipper spectra or Klipper raw recordings.

    \b
    gcode-feedopt identify --x resonances_x.csv --y resonances_y.csv -o mine.yaml
    gcode-feedopt identify --x raw_data_x.csv --y raw_data_y.csv -o mine.yaml --plot fit.png
    gcode-feedopt identify --x raw_x.csv --y raw_y.csv --base voron24 --flavour klipper -o v.yaml
    gcode-feedopt identify --x raw_x.csv --y raw_y.csv --base voron24 --klipper-config printer.cfg -o v.yaml
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
    shapers = read_input_shaper(klipper_cfg) if klipper_cfg else None
    fw_flavour = flavour or base_p.firmware.flavour
    if klipper_cfg and fw_flavour != "klipper":
        why = "--flavour" if flavour else f"--base {base}"
        raise click.UsageError(f"--klipper-config {klipper_cfg}: a printer.cfg is Klipper's, but "
                               f"the profile's firmware would be {fw_flavour} (from {why}); "
                               "give --flavour klipper or a Klipper base")
    inputs = [*x_files, *y_files, *profile_files(base), *([klipper_cfg] if klipper_cfg else [])]
    for f in inputs:
        check_input(f)
    check_profile_output(output, "-o", inputs)
    plot_t = check_outputs({"-o": output, "--plot": plot_path}, inputs=inputs,
                           suffixes={"-o": (".yaml", ".yml"), "--plot": PLOT_SUFFIXES}).get("--plot")
    axes = dict(base_p.axes)
    panels = {}
    for axis, files in (("x", x_files), ("y", y_files)):
        if files:
            axes[axis], panels[axis], warns = identify_axis(axis, files, n_modes, ex, segments)
            for w in warns:
                click.echo(f"warning: {w}", err=True)
            m = ", ".join(f"{md.freq_hz:.1f} Hz zeta {md.damping:.3f}" for md in axes[axis].modes)
            click.echo(f"{axis}: {m}")
    prov = dict(base_p.provenance)
    prov["identified_from"] = {"x": list(x_files), "y": list(y_files), "base": base}
    twin = dataclasses.replace(base_p.twin, priors={})
    out = pathlib.Path(output)
    files = ", ".join(pathlib.Path(f).name for f in (*x_files, *y_files))
    firmware = base_p.firmware
    if flavour and flavour != firmware.flavour:
        # G91 moves E relatively on Marlin, not on Klipper (docs/firmware.md)
        firmware = dataclasses.replace(firmware, flavour=flavour,
                                       g91_relative_e=flavour == "marlin")
    if shapers is not None:
        firmware = dataclasses.replace(firmware, input_shaper=shapers)
        for a, sh in shapers.items():
            click.echo(f"{a}: prints through input shaper {sh.describe()} ({klipper_cfg})")
    new = dataclasses.replace(
        base_p, name=name or out.stem, axes=axes, provenance=prov, twin=twin, source_path=None,
        firmware=firmware,
        description=description or (f"identified from {files} on {base_p.name} limits"
                                    + (f", {flavour} firmware" if flavour else "")))
    save_profile(new, out)
    click.echo(f"wrote {out}")
    if plot_path:
        with output_path(plot_t) as tmp:
            plot_fits(tmp, panels)
        click.echo(f"wrote {plot_path}")
