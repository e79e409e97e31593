"""``gcode-feedopt compare``: every method on the virtual machine with the same plant and
seed; the paper's Table 1 columns as a table (and JSON), Fig. 12 as a PNG."""

from __future__ import annotations

import functools
import json
import os
import time

import click

from ..inputs import check_input
from ..outputs import check_outputs, output_file, output_path
from ..pipeline import PLOT_SUFFIXES, check_plan_size, path_for, read_for
from ..plan.request import PlanRequest
from ..plot import plot_compare
from ..profile import load_profile
from ..vm.plant import Plant
from .options import AMAX, SEED, STRINGENCY, TOLERANCE, VMAX, profile_files
from .simulate import _parse_effects

COLUMNS = (("method", "method", "{}"), ("cycle_time_s", "cycle s", "{:.3f}"),
           ("contour_time_s", "contour s", "{:.3f}"),
           ("rms_gamma_um", "RMS γ µm", "{:.2f}"), ("within_fraction", "within", "{:.4f}"),
           ("prediction_rms_x_mm", "pred RMS x mm", "{}"),
           ("prediction_rms_y_mm", "pred RMS y mm", "{}"), ("compute_s", "compute s", "{:.2f}"),
           ("fallback_windows", "fallback", "{}"), ("relaxed_windows", "relaxed", "{}"))


def format_table(rows) -> str:
    head = [c[1] for c in COLUMNS]
    body = []
    for r in rows:
        cells = []
        for key, _, fmt in COLUMNS:
            v = r.get(key)
            if v is None:
                cells.append("–")
            elif fmt == "{}" and isinstance(v, float):
                cells.append(f"{v:.4f}")
            else:
                cells.append(fmt.format(v))
        body.append(cells)
    widths = [max(len(h), *(len(b[i]) for b in body)) for i, h in enumerate(head)]
    line = lambda cells: "  ".join(c.rjust(w) for c, w in zip(cells, widths))  # noqa: E731
    return "\n".join([line(head), line(["-" * w for w in widths]), *map(line, body)])


@click.command("compare")
@click.argument("gcode", type=click.Path(exists=True, dir_okay=False))
@click.option("--machine", "-m", required=True, help="Profile name (ender3pro, nomad3, voron24) or YAML path.")
@click.option("--methods", default="kinematic,conservative,pb,dd,pidd,oracle", show_default=True,
              help="Comma-separated methods to run.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Plant seed (same for all methods).")
@click.option("--effect", "effects", multiple=True, callback=_parse_effects, metavar="SPEC",
              help="Unknown effect in the plant (repeatable), e.g. sinusoid:axis=x,amp_mm=0.05.")
@click.option("--nominal/--drawn", default=True, show_default=True,
              help="Plant = the FRF set's mean response, or one seeded draw of it.")
@click.option("--tolerance", type=TOLERANCE, default=None,
              help="E_max, mm (default: the profile's).")
@click.option("--stringency", type=STRINGENCY, default=None,
              help="η (default: the profile's).")
@click.option("--vmax", type=VMAX, default=None, help="V_max, mm/s.")
@click.option("--amax", type=AMAX, default=None, help="A_max, mm/s².")
@click.option("--offline", is_flag=True, help="Do not learn between windows (dd/pidd keep their priors).")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), help="Write the rows as JSON ('-' for stdout).")
@click.option("--plot", "png", type=click.Path(dir_okay=False),
              help="Write the paper's Fig. 12: feed, acceleration, contour error, γ, prediction error.")
def compare(gcode, machine, methods, seed, effects, nominal, tolerance, stringency, vmax, amax,
            offline, json_path, png):
    """Run every method on the virtual machine (same plant, same seed) and print the paper's
    Table 1: cycle time, RMS tolerance violation γ, fraction of samples within tolerance,
    prediction RMS per axis, compute time.

    \b
    gcode-feedopt compare sample_gcode/butterfly.gcode --machine ender3pro \\
        --effect sinusoid:axis=x,amp_mm=0.05 --plot fig12.png
    """
    from pathlib import Path

    # heavy stages imported on use: `gcode-feedopt --help` imports every command module
    from ..optimize import METHODS
    from ..optimize.compare import run_compare

    chosen = [m.strip() for m in methods.split(",") if m.strip()]
    bad = [m for m in chosen if m not in METHODS]
    if bad or not chosen:
        raise click.BadParameter(f"unknown {', '.join(bad)}; use some of {', '.join(METHODS)}"
                                 if bad else f"no method given; use some of {', '.join(METHODS)}",
                                 param_hint="'--methods'")
    profile = load_profile(machine)
    check_input(gcode)
    targets = check_outputs({"--json": json_path, "--plot": png},
                            inputs=[gcode, *profile_files(machine)],
                            suffixes={"--plot": PLOT_SUFFIXES})
    req = PlanRequest.of(profile, tolerance_mm=tolerance, stringency=stringency,
                         vmax_mm_s=vmax, amax_mm_s2=amax)
    tol, eta = req.tolerance_mm, req.stringency
    path = path_for(read_for(Path(gcode), profile), profile)
    check_plan_size(path, profile, vmax, amax, where=str(gcode))
    plant = Plant(profile, seed=seed, effects=effects, nominal=nominal)
    t0 = time.perf_counter()
    runs = run_compare(path, profile, plant, methods=chosen, tolerance_mm=tol,
                       stringency=eta, vmax_mm_s=vmax, amax_mm_s2=amax, online=not offline)
    rows = [r.row() for r in runs]
    say = functools.partial(click.echo, err=json_path == "-")  # keep stdout pure JSON then
    say(f"{os.path.basename(gcode)} on {profile.name} ({'nominal' if nominal else 'drawn'} plant, "
               f"seed {seed}; E_max {tol} mm, η {eta}"
               + (", effects: " + " ".join(e.to_spec() for e in effects) if effects else "")
               + f"; {'offline' if offline else 'online learning'})")
    say(format_table(rows))
    say(f"total {time.perf_counter() - t0:.1f} s")
    if json_path:
        with output_file(targets["--json"], text=True) as fh:
            json.dump({"file": os.fspath(gcode), "machine": profile.name, "seed": seed,
                       "plant": "nominal" if nominal else "draw", "tolerance_mm": tol,
                       "stringency": eta, "effects": [e.to_dict() for e in effects],
                       "online": not offline, "rows": rows}, fh, indent=2)
            fh.write("\n")
    if png:
        with output_path(targets["--plot"]) as tmp:
            plot_compare(runs, tmp, tolerance_mm=tol,
                         title=f"{os.path.basename(gcode)} on {profile.name}, η {eta}")
