"""``gcode-feedopt batch DIR [-o OUTDIR] [-j N] --machine M`` — a folder of jobs."""

from __future__ import annotations

import os
import pathlib
import sys

import click

from ..hosts.batch import find_jobs, notes_text, run_batch, table
from ..pipeline import METHODS
from ..plan.speed import SPEEDS
from ..procs import signal_name
from ..profile import load_profile
from ..gcode.features import parse_feature_tolerance
from ..firmware import ACCELS
from .options import AMAX, FEATURE_TOLERANCE_HELP, STRINGENCY, TOLERANCE, VMAX, speed_policy


@click.command("batch")
@click.argument("folder", type=click.Path(exists=True, file_okay=False, path_type=pathlib.Path))
@click.option("-o", "--outdir", type=click.Path(file_okay=False, path_type=pathlib.Path),
              help="Write results here (default: edit the files in place).")
@click.option("-j", "--jobs", type=click.IntRange(1, 256), default=os.cpu_count() or 1,
              show_default=True, help="Parallel processes.")
@click.option("--machine", "-m", required=True, help="Built-in profile or profile .yaml.")
@click.option("--method", type=click.Choice(METHODS), default="pidd", show_default=True,
              help="As for optimize (pidd: the digital twin keeps the tolerance).")
@click.option("--tolerance", type=TOLERANCE, metavar="MM",
              help="Contour-error tolerance E_max, mm (default: the profile's).")
@click.option("--feature-tolerance", metavar="F=MM,...", help=FEATURE_TOLERANCE_HELP)
@click.option("--stringency", type=STRINGENCY, metavar="P",
              help="Fraction of samples that must be within tolerance (default: the profile's).")
@click.option("--vmax", type=VMAX, metavar="MM_S", help="Override the feed limit, mm/s.")
@click.option("--amax", type=AMAX, metavar="MM_S2",
              help="Override the X/Y acceleration limit, mm/s².")
@click.option("--mode", type=click.Choice(["refeed", "sampled"]), default="refeed",
              show_default=True, help="As for optimize.")
@click.option("--speed", type=click.Choice(SPEEDS), default=SPEEDS[0], show_default=True,
              help="As for optimize (slicer: no move faster than its sliced F).")
@click.option("--use-slicer-feed", is_flag=True, hidden=True,
              help="Old name of --speed slicer (now the default).")
@click.option("--accel", type=click.Choice(ACCELS), default=ACCELS[0], show_default=True,
              help="As for optimize (plan: the plan's accelerations and junctions over the "
                   "file's lower ones; file: the file's kept).")
@click.option("--allow-slower", is_flag=True,
              help="As for optimize (by default a file our plan would slow down is kept).")
@click.option("--force", is_flag=True, help="Process files that were processed before.")
@click.option("--report", "report_dir", type=click.Path(file_okay=False, path_type=pathlib.Path),
              metavar="DIR", help="Write each file's JSON report (as optimize --report) to "
                                  "DIR/<name>.json; DIR is created if its parent exists.")
def batch(folder, outdir, jobs, machine, method, tolerance, feature_tolerance, stringency, vmax,
          amax, mode, speed, use_slicer_feed, accel, allow_slower, force, report_dir):
    """Optimize every G-code file in FOLDER; print a summary table; exit 1 if any failed."""
    load_profile(machine)  # a bad machine fails once, here, not once per file
    opts = {"method": method, "tolerance_mm": tolerance, "stringency": stringency,
            "vmax_mm_s": vmax, "amax_mm_s2": amax, "mode": mode,
            "speed": speed_policy(speed, use_slicer_feed), "accel": accel,
            "allow_slower": allow_slower,
            "force": force}
    ft = parse_feature_tolerance(feature_tolerance)
    if ft is not None:  # only when given: batch's settings record stays as it was
        opts["feature_tolerance"] = ft
    total = len(find_jobs(folder))
    done = [0]
    tty = sys.stderr.isatty()

    def progress(r):
        done[0] += 1
        if tty:
            click.echo(f"\r[{done[0]}/{total}] {r.file[:50]:50s}", err=True, nl=False)

    results, signum = run_batch(folder, outdir, machine, opts, jobs, progress,
                                report_dir=report_dir)
    if tty:
        click.echo("", err=True)
    click.echo(table(results))
    notes = notes_text(results)
    if notes:
        click.echo(notes)
    failed = [r for r in results if r.status == "failed"]
    if signum is not None:
        stopped = sum(r.status == "interrupted" for r in results)
        click.echo(f"gcode-feedopt: batch stopped by {signal_name(signum)}: {stopped} of "
                   f"{len(results)} files not written (untouched), {len(failed)} failed", err=True)
        sys.exit(128 + signum)
    if failed:
        click.echo(f"batch: {len(failed)} of {len(results)} failed", err=True)
        sys.exit(1)
