"""``gcode-feedopt diagnose``: what the twin gets wrong on a log, its cause, the gain of the
extended model on held-out data (closedloop.diagnose)."""

from __future__ import annotations

import functools
import json

import click

from ..closedloop.diagnose_plot import plot_diagnosis
from ..inputs import check_input
from ..outputs import check_outputs, output_path, write_text
from ..pipeline import PLOT_SUFFIXES
from ..profile import load_profile
from ..profile.io import check_profile_output, save_profile
from .options import Bounded, profile_files


@click.command("diagnose")
@click.argument("log_path", metavar="LOG", type=click.Path(exists=True, dir_okay=False))
@click.option("--machine", "-m", required=True, help="Profile name (ender3pro, nomad3, voron24) or YAML path.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False),
              help="Write the diagnosis as JSON here ('-' for stdout).")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False),
              help="PNG of the residual before/after and its spectrum.")
@click.option("--fit-fraction", type=Bounded("fit_fraction"), default=0.6, show_default=True,
              help="Fraction of the log (from its start) the extension is fitted on; the rest is held out.")
@click.option("--output", "-o", "out_profile", type=click.Path(dir_okay=False),
              help="Write the extended profile here (YAML): every named effect with its fitted "
                   "parameters in axes.<axis>.effects (docs/diagnose.md).")
@click.option("--raw-axis", type=click.Choice(["x", "y"]), default="x", show_default=True,
              help="For a Klipper raw recording: the profile axis it is compared with.")
def diagnose(log_path, machine, json_path, plot_path, fit_fraction, out_profile, raw_axis):
    """Diagnose LOG (an encoder log from `simulate --log`, or a Klipper raw accelerometer
    recording of a resonance test) against the twin of --machine.

    \b
    gcode-feedopt diagnose --machine ender3pro part.csv --json d.json --plot d.png
    gcode-feedopt diagnose -m ender3pro part.csv -o extended.yaml   (then optimize -m extended.yaml)
    """
    # heavy stages imported on use: `gcode-feedopt --help` imports every command module
    from ..closedloop.diagnose import diagnose_log, leftover_sentence
    from ..closedloop.logs import load_log

    profile = load_profile(machine)
    check_input(log_path)
    inputs = [log_path, *profile_files(machine)]
    targets = check_outputs({"--json": json_path, "--plot": plot_path, "-o": out_profile},
                            inputs=inputs, suffixes={"--plot": PLOT_SUFFIXES,
                                                     "-o": (".yaml", ".yml")})
    if out_profile:
        check_profile_output(out_profile, "-o", inputs)
    log = load_log(log_path, profile, raw_axis=raw_axis)
    d = diagnose_log(log, profile, fit_fraction=fit_fraction)
    out = d.to_dict()
    out["log"] = {"path": log.source, "kind": log.kind, "samples": int(log.cmd_mm.shape[0]),
                  "ts_s": log.ts_s, "warmup_samples": int(log.warmup), **log.info}
    rr, ho = d.residual_rms_mm, d.holdout_rms_mm
    say = functools.partial(click.echo, err=json_path == "-")  # keep stdout pure JSON then
    say(f"residual RMS  x {rr['x'] * 1e3:.2f} µm   y {rr['y'] * 1e3:.2f} µm")
    for e in d.effects:
        params = ", ".join(f"{k}={v:.5g}" if isinstance(v, float) else f"{k}={v}"
                           for k, v in e["params"].items() if k not in ("tie", "phase_rad"))
        say(f"effect        {e['kind']} on {e['axis']} ({params}) "
                   f"confidence {e['confidence']:.2f}")
        tie = e["params"].get("tie")
        if tie:
            tp = ", ".join(f"{k}={v:.5g}" for k, v in tie["params"].items() if isinstance(v, float))
            say(f"              tie: {tie['kind']} ({tp}) explains the held-out part as "
                       "well; the two are not told apart by this log")
    for ax in ("x", "y"):
        if d.leftover[ax]["significant"]:
            say(f"left over     {leftover_sentence(ax, d.leftover[ax])}")
    for ax in ("x", "y"):
        line = (f"held-out RMS  {ax}: {ho['before'][ax] * 1e3:.2f} -> {ho['after'][ax] * 1e3:.2f} µm "
                "(the extended profile)")
        if "after_fitted" in ho and abs(ho["after_fitted"][ax] - ho["after"][ax]) > 1e-7:
            line += f", {ho['after_fitted'][ax] * 1e3:.2f} µm with this log's fitted phase"
        say(line)
    if json_path:
        text = json.dumps(out, indent=2)
        if json_path == "-":
            click.echo(text)
        else:
            write_text(targets["--json"], text + "\n")
    if out_profile:
        import dataclasses

        from ..closedloop.extend import extend_profile  # on use, as above

        ext = extend_profile(profile, d.effects, source=str(log_path))
        ext = dataclasses.replace(ext, name=ext.name + "-extended")
        save_profile(ext, out_profile)
        say(f"wrote {out_profile}")
    if plot_path:
        with output_path(targets["--plot"]) as tmp:
            plot_diagnosis(tmp, d, log.ts_s, title=str(log_path))
