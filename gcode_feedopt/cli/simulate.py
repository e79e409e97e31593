"""``gcode-feedopt simulate``: run a G-code file on the virtual machine.

G-code -> firmware model (``vm.firmware``, Marlin or Klipper per profile) -> commanded
trajectory -> plant (one seeded draw of the profile's FRFs plus ``--effect``s) -> metrics,
an optional encoder log (``--log``) and JSON report (``--report``).

The command over ``gcode_feedopt.simulation`` (``simulate_file``), which other stages and
the benchmarks call without click.
"""

from __future__ import annotations

import json
import os
import sys
import time

import click

from ..inputs import check_input
from ..outputs import check_outputs, write_text
from ..profile import load_profile
from ..simulation import CONTOUR_ON, simulate_file
from ..vm import effects as fx
from ..vm.log import write_log
from .options import SEED, TOLERANCE, profile_files

#: largest |value| of an effect parameter (mm, Hz, s, scale): 1e308 ran and gave inf metrics
MAX_EFFECT_ABS = 1e4


def _parse_effects(ctx, param, values):
    out = []
    for spec in values:
        try:
            e = fx.parse_effect(spec)
        except fx.EffectSpecError as exc:
            raise click.BadParameter(str(exc), ctx=ctx, param=param) from None
        for k, v in e.params().items():
            if isinstance(v, float) and abs(v) > MAX_EFFECT_ABS:
                raise click.BadParameter(f"{spec[:60]!r}: {k}={v:g} is beyond "
                                         f"±{MAX_EFFECT_ABS:g}; give a physical value",
                                         ctx=ctx, param=param)
        out.append(e)
    return tuple(out)


@click.command("simulate")
@click.argument("gcode", type=click.Path(exists=True, dir_okay=False))
@click.option("--machine", "-m", required=True, help="Profile name (ender3pro, nomad3, voron24) or YAML path.")
@click.option("--seed", type=SEED, default=0, show_default=True,
              help="Seed of the FRF draw (the machine) and of the sensor noise.")
@click.option("--effect", "effects", multiple=True, callback=_parse_effects, metavar="SPEC",
              help="Unknown effect to plant, e.g. sinusoid:axis=x,amp_mm=0.05,freq_hz=116.7 "
                   "(repeatable; kinds: sinusoid, " + ", ".join(fx.EFFECT_TYPES) + ").")
@click.option("--log", "log_path", type=click.Path(dir_okay=False, allow_dash=False),
              help="Write the encoder log (t,x_cmd,y_cmd,x,y,z_cmd,z,e_cmd) here ('-' for stdout).")
@click.option("--report", "report_path", type=click.Path(dir_okay=False),
              help="Write the metrics as JSON here ('-' for stdout).")
@click.option("--tolerance", "tol_mm", type=TOLERANCE,
              help="Contour tolerance E_max, mm [default: the profile's].")
@click.option("--contour-on", type=click.Choice(CONTOUR_ON), default="extrusion", show_default=True,
              help="Samples the contour error is judged on: extruding moves, or all XY motion.")
@click.option("--nominal", is_flag=True,
              help="Use the mean response of the profile's FRFs instead of a seeded draw.")
@click.option("--quiet", "-q", is_flag=True, help="Do not print the metrics.")
def simulate(gcode, machine, seed, effects, log_path, report_path, tol_mm, contour_on, nominal, quiet):
    """Run GCODE on the virtual machine: firmware model, servo plant with unknown effects;
    print cycle time, contour error and tolerance violation.

    \b
    gcode-feedopt simulate part.gcode --machine ender3pro --log part.csv --report part.json
    gcode-feedopt simulate part.gcode -m ender3pro --seed 3 --effect backlash:axis=x,magnitude_mm=0.05
    """
    t_start = time.perf_counter()
    profile = load_profile(machine)
    check_input(gcode)
    targets = check_outputs({"--log": log_path, "--report": report_path},
                            inputs=[gcode, *profile_files(machine)])
    res = simulate_file(gcode, profile, seed=seed, effects=effects, tol_mm=tol_mm, contour_on=contour_on,
                        nominal=nominal)
    if log_path:
        t0 = time.perf_counter()
        tr, out = res.trajectory, res.output
        write_log(targets["--log"], tr.t_s, tr.pos_mm, out.measured_mm, tr.e_mm)
        res.timings_s["log"] = time.perf_counter() - t0
    wall = time.perf_counter() - t_start
    m = res.metrics
    if not quiet:
        err = "-" in (report_path, log_path)  # keep stdout pure JSON / CSV then
        click.echo(f"{os.path.basename(gcode)} on {profile.name} ({'nominal' if nominal else 'drawn'} plant, seed {seed}"
                   + (", effects: " + " ".join(e.to_spec() for e in effects) if effects else "") + ")", err=err)
        click.echo(m.summary(), err=err)
        click.echo(f"simulated in     {wall:12.3f} s ({m.cycle_time_s / wall:.0f}x faster than the print)", err=err)
    if report_path:
        report = {
            "file": os.fspath(gcode),
            "machine": profile.name,
            "seed": seed,
            "plant": "nominal" if nominal else "draw",
            "effects": [e.to_dict() for e in effects],
            "ts_s": res.trajectory.ts_s,
            **m.to_dict(),
            "timings_s": {k: round(v, 4) for k, v in res.timings_s.items()},
            "wall_s": round(wall, 4),
        }
        text = json.dumps(report, indent=2) + "\n"
        if report_path == "-":
            sys.stdout.write(text)
        else:
            write_text(targets["--report"], text)
