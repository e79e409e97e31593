"""``gcode-feedopt profile build|show|check`` — machine profiles."""

from __future__ import annotations

import dataclasses
import json
import pathlib

import click

from ..profile import load_profile, save_profile
from ..profile.build import build_from_frfs
from ..profile.io import check_profile_output
from ..profile.klipper_cfg import read_input_shaper
from .options import profile_files


@click.group("profile")
def profile():
    """Build, show and check machine profiles."""


def _parse_build_args(args):
    """``--frf-x A.csv B.csv ... --frf-y C.csv ... [--base P] [--name N] -o OUT`` (the file
    lists run until the next option, as the issue's command line writes them)."""
    opts = {"frf_x": [], "frf_y": [], "base": "ender3pro", "name": None, "description": None,
            "output": None, "klipper_cfg": None}
    cur = None
    it = iter(args)
    for tok in it:
        if tok in ("--frf-x", "--frf-y"):
            cur = opts["frf_x"] if tok == "--frf-x" else opts["frf_y"]
        elif tok in ("--base", "--name", "--description", "-o", "--output", "--klipper-config"):
            key = {"--base": "base", "--name": "name", "--description": "description",
                   "-o": "output", "--output": "output", "--klipper-config": "klipper_cfg"}[tok]
            try:
                opts[key] = next(it)
            except StopIteration:
                raise click.UsageError(f"{tok} needs a value") from None
            cur = None
        elif tok.startswith("-"):
            raise click.UsageError(f"unknown option {tok}; see gcode-feedopt profile build --help")
        elif cur is None:
            raise click.UsageError(f"{tok}: a file must follow --frf-x or --frf-y")
        else:
            if not pathlib.Path(tok).is_file():
                raise click.UsageError(f"{tok}: no such FRF file")
            cur.append(tok)
    if opts["output"] is None:
        raise click.UsageError("give -o OUT.yaml")
    return opts


@profile.command("build", context_settings={"ignore_unknown_options": True})
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
def build(args):
    """Build a profile from measured FRFs, limits taken from the base profile.

    \b
    gcode-feedopt profile build --frf-x A.csv B.csv ... --frf-y C.csv ... [--base ender3pro]
                                [--name NAME] [--description TEXT] -o plant.yaml

    \b
    Options (each file list runs to the next option):
      --frf-x FILE...     X's FRF CSVs (header freq_hz,real,imag), one measurement each
      --frf-y FILE...     Y's FRF CSVs
      --base PROFILE      limits, firmware and twin settings from this profile [ender3pro]
      --name NAME         the new profile's name [the output file's stem]
      --description TEXT  its description [built from measured FRFs on BASE limits]
      --klipper-config F  the printer.cfg whose [input_shaper] the printer prints with
                          (firmware.input_shaper; the FRFs measured with it off)
      -o, --output OUT    the YAML to write (required)
    """
    o = _parse_build_args(args)
    frf_x, frf_y, base, name = o["frf_x"], o["frf_y"], o["base"], o["name"]
    output = pathlib.Path(o["output"])
    if not frf_x and not frf_y:
        raise click.UsageError("give --frf-x and/or --frf-y files")
    base_p = load_profile(base)
    cfg = o.get("klipper_cfg")
    check_profile_output(output, "-o", [*frf_x, *frf_y, *profile_files(base), *([cfg] if cfg else [])])
    if cfg and base_p.firmware.flavour != "klipper":
        raise click.UsageError(f"--klipper-config {cfg}: a printer.cfg is Klipper's, but --base "
                               f"{base}'s firmware is {base_p.firmware.flavour}; take a Klipper "
                               "base (voron24) or build on your own Klipper profile")
    if cfg:
        base_p = dataclasses.replace(base_p, firmware=dataclasses.replace(
            base_p.firmware, input_shaper=read_input_shaper(cfg)))
    new, lines = build_from_frfs(base_p, {"x": frf_x, "y": frf_y},
                                 name=name or output.stem, description=o["description"])
    for line in lines:
        click.echo(f"profile build: {line}", err=True)
    save_profile(new, output)
    load_profile(output)  # round trip: what we wrote must load
    click.echo(f"profile build: wrote {output}", err=True)


def _summary(p) -> dict:
    axes = {}
    for a, ax in p.axes.items():
        d = {"modes": [{"freq_hz": m.freq_hz, "damping": m.damping, "gain": m.gain}
                       for m in ax.modes]}
        if ax.frf is not None:
            d["frf_measurements"] = ax.frf.n_measurements
            d["frf_band_hz"] = [float(ax.frf.freq_hz[0]), float(ax.frf.freq_hz[-1])]
        d["provenance"] = {k: v for k, v in ax.provenance.items() if k != "measurements"}
        axes[a] = d
    L = p.limits
    return {"name": p.name, "description": p.description, "ts_s": p.ts_s,
            "limits": dataclasses.asdict(L), "firmware": dataclasses.asdict(p.firmware),
            "twin": {"n2": p.twin.n2, "n3": p.twin.n3, "sigma_eps_mm": p.twin.sigma_eps_mm,
                     "coef_variance": p.twin.coef_variance, "n_taps": p.twin.n_taps,
                     "physics": p.twin.physics, "dc_gain": p.twin.dc_gain,
                     "priors": {a: {"learned_from": list(pr.learned_from)}
                                for a, pr in p.twin.priors.items()}},
            "axes": axes, "provenance": p.provenance, "source": p.source_path}


@profile.command("show")
@click.argument("name_or_path")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def show(name_or_path, as_json):
    """Print limits, modes per axis and provenance of a profile."""
    p = load_profile(name_or_path)
    s = _summary(p)
    if as_json:
        click.echo(json.dumps(s, indent=2, default=str))
        return
    L = p.limits
    click.echo(f"{p.name}: {p.description}")
    click.echo(f"  Ts {p.ts_s * 1000:g} ms; V_max {L.vmax_mm_s:g} mm/s, A_max {L.amax_mm_s2:g} mm/s², "
               f"tolerance {L.tolerance_mm:g} mm at {L.stringency:.0%}; firmware {p.firmware.flavour}")
    for a, d in s["axes"].items():
        modes = ", ".join(f"{m['freq_hz']:.1f} Hz ζ={m['damping']:.3f}" for m in d["modes"]) or "none fitted"
        n = d.get("frf_measurements", 0)
        shaper = p.firmware.input_shaper.get(a)
        shaped = f"; printed through input shaper {shaper.describe()}" if shaper else ""
        click.echo(f"  {a}: {n} FRFs; modes {modes}; {d['provenance'].get('kind', '?')}{shaped}")
    for k, v in p.provenance.items():
        click.echo(f"  provenance.{k}: {v}")


@profile.command("check")
@click.argument("name_or_path")
def check(name_or_path):
    """Validate a profile (exit 0 and 'ok', or the one-line error)."""
    p = load_profile(name_or_path)
    click.echo(f"{p.name}: ok")
