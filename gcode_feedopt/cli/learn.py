"""``gcode-feedopt learn``: bounded Bayesian update of the twin's priors from logs
(closedloop.learn)."""

from __future__ import annotations

import sys

import click

from ..errors import LogError
from ..inputs import check_input
from ..profile import load_profile
from ..profile.io import check_profile_output, save_profile
from .options import Progress, profile_files


@click.command("learn")
@click.argument("logs", metavar="LOG...", nargs=-1, required=True,
                type=click.Path(exists=True, dir_okay=False))
@click.option("--machine", "-m", required=True, help="Profile name (ender3pro, nomad3, voron24) or YAML path.")
@click.option("--output", "-o", "out_path", required=True, type=click.Path(dir_okay=False),
              help="Updated profile (YAML); its twin.priors record what was learned from what.")
@click.option("--skip-bad", is_flag=True, help="Skip a refused log (one line on stderr) instead of stopping.")
def learn(logs, machine, out_path, skip_bad):
    """Update the twin priors of --machine from encoder logs of earlier prints.

    \b
    gcode-feedopt learn --machine ender3pro part1.csv part2.csv -o updated.yaml
    """
    # heavy stages imported on use: `gcode-feedopt --help` imports every command module
    from ..closedloop.learn import learn_logs
    from ..closedloop.logs import load_log

    profile = load_profile(machine)
    for path in logs:
        check_input(path)
    check_profile_output(out_path, "-o", [*logs, *profile_files(machine)])
    # a whole-print log takes a minute: one self-overwriting line on a terminal, nothing else
    progress = Progress("learn") if sys.stderr.isatty() else None
    try:
        profile, n_ok = _learn_each(logs, profile, skip_bad, progress, load_log, learn_logs)
    finally:
        if progress is not None:
            progress.done()
    if n_ok == 0:
        raise LogError("no log was learned from; nothing written")
    save_profile(profile, out_path)
    click.echo(f"wrote {out_path} ({n_ok} log(s))")


def _learn_each(logs, profile, skip_bad, progress, load_log, learn_logs):
    """Learn from each log in turn; the updated profile and how many logs were learned from."""
    def say(stage):
        if progress is not None:
            progress(stage)

    n_ok = 0
    for i, path in enumerate(logs, 1):
        try:
            say(f"[{i}/{len(logs)}] reading {path}")
            log = load_log(path, profile)
            say(f"[{i}/{len(logs)}] learning from {path}")
            profile, records = learn_logs(profile, [log])
        except LogError as exc:
            if progress is not None:
                progress.clear()
            if not skip_bad:
                raise
            click.echo(f"gcode-feedopt: skipped: {exc}", err=True)
            continue
        n_ok += 1
        if progress is not None:
            progress.clear()
        for r in records:
            pr = r["prediction_rms_mm"]
            warm = (f", after a {r['warmup_samples']}-sample warm-up"
                    if r.get("warmup_samples") else "")
            click.echo(f"{path}: {r['axis']}: prediction RMS {pr['before'] * 1e3:.1f} -> "
                       f"{pr['after'] * 1e3:.1f} µm (step x{r['step_scale']:.3g}"
                       f"{', bounded' if r['step_clipped'] else ''}{warm}); what the twin "
                       f"cannot predict: {r['noise_level_mm'] * 1e3:.1f} µm at rest + "
                       f"{r['noise_per_speed_s'] * 1e3:.2f} ms x speed + a filter of the "
                       f"motion ({r.get('residual_filter_log_rms_mm', 0.0) * 1e3:.1f} µm RMS "
                       f"on this log)")
    return profile, n_ok
