"""``gcode-feedopt [optimize] IN [-o OUT] --machine M ...`` — the main job."""

from __future__ import annotations

import pathlib
import sys

import click

from ..errors import FeedOptError
from ..gcode.features import parse_feature_tolerance
from ..hosts import prusaslicer
from ..outputs import write_text
from ..pipeline import METHODS, Options, check_run_outputs, optimize_file
from ..profile import load_profile
from ..plan.speed import SPEEDS
from ..firmware import ACCELS
from .options import (ACCEL_HELP, AMAX, FEATURE_TOLERANCE_HELP, STRINGENCY, TOLERANCE, VMAX,
                      Progress, profile_files, speed_policy)


@click.command("optimize")
@click.argument("gcode", type=click.Path(dir_okay=False, path_type=pathlib.Path))
@click.option("-o", "--output", type=click.Path(dir_okay=False, path_type=pathlib.Path),
              help="Write here; without it the input is edited in place (PrusaSlicer's contract).")
@click.option("--machine", "-m", required=True,
              help="Built-in profile (ender3pro, nomad3, voron24) or a profile .yaml path.")
@click.option("--method", type=click.Choice(METHODS), default="pidd", show_default=True,
              help="pidd: the digital twin keeps the contour error within the tolerance; "
                   "kinematic: the firmware's limits only (fastest, no error model); "
                   "pb: the twin's physics alone; conservative: uniform limits lowered until "
                   "the profile's nominal machine holds the tolerance.")
@click.option("--tolerance", type=TOLERANCE, metavar="MM",
              help="Contour-error tolerance E_max, mm (default: the profile's).")
@click.option("--feature-tolerance", metavar="F=MM,...", help=FEATURE_TOLERANCE_HELP)
@click.option("--stringency", type=STRINGENCY, metavar="P",
              help="Fraction of samples that must be within tolerance (default: the profile's).")
@click.option("--vmax", type=VMAX, metavar="MM_S",
              help="Override the profile's feed limit, mm/s.")
@click.option("--amax", type=AMAX, metavar="MM_S2",
              help="Override the profile's X/Y acceleration limit, mm/s².")
@click.option("--mode", type=click.Choice(["refeed", "sampled"]), default="refeed", show_default=True,
              help="refeed: the original moves with new F values; sampled: one G1 per Ts.")
@click.option("--speed", type=click.Choice(SPEEDS), default=SPEEDS[0], show_default=True,
              help="slicer: no move faster than its sliced F (first layer, walls, bridges, "
                   "cooling slow-downs kept; the time comes from acceleration and cornering); "
                   "machine: up to the machine's limits, first layer and the profile's "
                   "volumetric limit kept.")
@click.option("--use-slicer-feed", is_flag=True, hidden=True,
              help="Old name of --speed slicer (now the default).")
@click.option("--accel", type=click.Choice(ACCELS), default=ACCELS[0], show_default=True,
              help=ACCEL_HELP)
@click.option("--allow-slower", is_flag=True,
              help="Write the output even when the firmware would run it slower than the "
                   "input (by default the input is kept as it was, and the summary says why).")
@click.option("--trajectory", type=click.Path(dir_okay=False), metavar="CSV",
              help="Also write the planned trajectory t,x,y,z,e (s, mm), one row per Ts.")
@click.option("--report", "report_path", type=click.Path(dir_okay=False), metavar="JSON",
              help="Write the run's figures as JSON ('-' for stdout).")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), metavar="PNG",
              help="Write a PNG: XY path coloured by speed, feed along the print.")
@click.option("--dry-run", is_flag=True, help="Plan and report, write nothing.")
@click.option("--force", is_flag=True, help="Process a file that was processed before.")
@click.option("--quiet", "-q", is_flag=True, help="No summary on stderr.")
def optimize(gcode, output, machine, method, tolerance, feature_tolerance, stringency, vmax,
             amax, mode, speed, use_slicer_feed, accel, allow_slower, trajectory, report_path,
             plot_path, dry_run, force, quiet):
    """Re-time GCODE for MACHINE and write it (in place without -o)."""
    in_slicer = prusaslicer.running_in_slicer()
    try:
        _run(gcode, output, machine, method, tolerance, stringency, vmax, amax, mode,
             speed_policy(speed, use_slicer_feed), allow_slower, trajectory, report_path,
             plot_path, dry_run, force, quiet, in_slicer,
             parse_feature_tolerance(feature_tolerance), accel)
    except FeedOptError as exc:
        if in_slicer:  # stderr is lost on Windows: leave the reason beside the G-code
            log = prusaslicer.write_failure_log(gcode, str(exc))
            if log is not None:
                exc.args = (f"{exc} (also written to {log})",)
        raise


def _run(gcode, output, machine, method, tolerance, stringency, vmax, amax, mode,
         speed, allow_slower, trajectory, report_path, plot_path, dry_run, force, quiet,
         in_slicer, feature_tolerance=None, accel=ACCELS[0]):
    opts = Options(method=method, tolerance_mm=tolerance, stringency=stringency, vmax_mm_s=vmax,
                   amax_mm_s2=amax, mode=mode, speed=speed, accel=accel,
                   allow_slower=allow_slower, force=force,
                   dry_run=dry_run, trajectory=trajectory, plot=plot_path,
                   feature_tolerance=feature_tolerance)
    profile = load_profile(machine)
    # every output checked before anything is read, planned or written
    targets = check_run_outputs(gcode, output, opts, {"--report": report_path},
                                inputs=profile_files(machine))
    progress = Progress(pathlib.Path(gcode).name) if not quiet and sys.stderr.isatty() else None
    try:
        rep = optimize_file(gcode, output, profile, opts, progress=progress)
    finally:
        if progress is not None:
            progress.done()
    if in_slicer:
        rep.notes.extend(prusaslicer.limit_disagreements(profile))
        name = prusaslicer.output_name()
        if name:
            rep.extra["slicer_output_name"] = name
    if report_path == "-":
        click.echo(rep.to_json())
    elif report_path:
        write_text(targets["--report"], rep.to_json() + "\n")
    if not quiet:
        click.echo(rep.summary(), err=True)
    elif rep.extra.get("kept_input"):  # nothing was done: said even when quiet
        click.echo(f"gcode-feedopt: {rep.input}: "
                   + next(n for n in rep.notes if n.startswith("kept the input")), err=True)
    sys.stderr.flush()

