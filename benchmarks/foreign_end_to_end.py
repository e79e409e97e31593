"""The optimizer on machines it was not built from (issue 19, point 7, on foreign physics).

For each drawn machine of tests/foreign/machines.py: a profile built from its FRFs (as
`profile build` does) with the scenario's V and A; the butterfly planned by kinematic,
conservative (the largest uniform scale of the limits that passes *on the foreign plant*: the
paper's rule, tuned on the plant) and pidd (the profile's twin only); each plan executed on the
foreign plant (the logs' plant of the data set, noise-free) and judged there: cycle time, RMS γ
against (1 − η)·E_max, fraction within E_max. ``pidd+learned``: pidd again after one print with
pidd on the foreign plant, its encoder log (1 µm noise) ``learn``ed — the closed loop on physics
the twin was not built from.

    python benchmarks/foreign_end_to_end.py                # seeds 0-9, η 0.95
    python benchmarks/foreign_end_to_end.py --seeds 1 6 --eta 0.9 0.99 --tol 0.05
    python benchmarks/foreign_end_to_end.py --seeds 0 --amax 3000 --tol 0.1 --prints 4

``--calibration``: also, per axis, how the learned twin's interval covers the print it plans
(RMS of error/σ, share inside the 99 % interval).
``--prints N``: also print after print, each planned with the profile learned so far and its
log ``learn``ed into it (N prints, N − 1 learned).
``--shaper mzv`` (``--causal``): the machines print through an input shaper at their dominant
modes (measured without it); the profile states it, unless ``--unstated``.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile
import warnings

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "benchmarks")]

from end_to_end import run, scenario_path, with_limits  # noqa: E402
from gcode_feedopt.errors import FeedOptError  # noqa: E402
from independent import bench_a_profile  # noqa: E402
from foreign import stated  # noqa: E402
from tests.foreign.machines import ForeignPlant, make_machine, with_shaper, write_dataset  # noqa: E402


def learned(path, prof, plant, tol, eta, tmp):
    """The profile after one pidd print on ``plant`` (closedloop.learn on its encoder log)."""
    import numpy as np

    from gcode_feedopt.closedloop.learn import learn_logs
    from gcode_feedopt.closedloop.logs import load_log
    from gcode_feedopt.optimize.methods import plan_schedule, vm_trajectory
    from gcode_feedopt.vm.log import write_log

    sch = plan_schedule("pidd", path, prof, tolerance_mm=tol, stringency=eta)
    tr = vm_trajectory(path, sch.s_mm, sch.ts_s)
    act = plant.run(tr)
    noisy = act + np.column_stack([0.001 * np.random.default_rng(7).standard_normal((len(act), 2)),
                                   np.zeros(len(act))])
    log = tmp / "first_print.csv"
    write_log(log, tr.t_s, tr.pos_mm, noisy, tr.e_mm)
    return learn_logs(prof, [load_log(log, prof)])[0]


def calibration(path, prof, plant, tol, eta) -> str:
    """How the twin of ``prof`` covers the print pidd plans with it: per axis, the RMS of
    (executed − the twin's open-loop mean) / its σ and the share of samples inside the 99 %
    interval (what ``predict`` shows for that plan)."""
    import numpy as np

    from gcode_feedopt.optimize.methods import plan_schedule, vm_trajectory
    from gcode_feedopt.twin.model import axis_twin

    sch = plan_schedule("pidd", path, prof, tolerance_mm=tol, stringency=eta)
    tr = vm_trajectory(path, sch.s_mm, sch.ts_s)
    act = plant.run(tr)
    out = []
    for i, ax in enumerate("xy"):
        mean, std = axis_twin(prof, ax).run(tr.pos_mm[:, i], None, learn=False)
        z = (act[:, i] - mean) / std
        out.append(f"{ax} error {1e3 * np.sqrt(np.mean((act[:, i] - mean) ** 2)):.1f} µm, "
                   f"median σ {1e3 * np.median(std):.2f} µm, RMS z {np.sqrt(np.mean(z * z)):.2f}, "
                   f"{100 * np.mean(np.abs(z) < 2.576):.1f} % inside 99 %")
    return "; ".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=list(range(10)))
    ap.add_argument("--eta", type=float, nargs="*", default=[0.95])
    ap.add_argument("--tol", type=float, default=0.05, help="E_max, mm")
    ap.add_argument("--vmax", type=float, default=150.0)
    ap.add_argument("--amax", type=float, default=5000.0)
    ap.add_argument("--prints", type=int, default=1,
                    help="also N prints in sequence, each learned into the profile")
    ap.add_argument("--calibration", action="store_true",
                    help="also how the learned twin's interval covers the print it plans")
    ap.add_argument("--shaper", choices=("zv", "zvd", "mzv"), default=None,
                    help="print through this input shaper at the dominant modes")
    ap.add_argument("--causal", action="store_true", help="the shaper's pulses causal (Marlin)")
    ap.add_argument("--unstated", action="store_true",
                    help="the profile does not state the shaper")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="foreign-e2e-"))
    print(f"butterfly, V {args.vmax:g} mm/s, A {args.amax:g} mm/s², E_max {args.tol:g} mm; "
          "plans executed on the foreign plant\n")
    print("| seed | kind | η | kinematic s | conservative s (scale) | pidd s | pidd/cons. | "
          "pidd RMS γ µm (limit) | pidd within | kinematic within | pidd+learned s | "
          "its RMS γ µm | its within |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for seed in args.seeds:
        mach = make_machine(seed)
        if args.shaper:
            mach = with_shaper(mach, args.shaper, centred=not args.causal)
        out = tmp / f"foreign-{seed}"
        labels = write_dataset(mach, out, effects=False)
        labels = json.loads((out / "labels.json").read_text())
        prof = with_limits(bench_a_profile(out, out.name), args.vmax, args.amax)
        if mach.shapers and not args.unstated:
            prof = stated(prof, mach)
        path = scenario_path("butterfly", prof, tmp)
        plant = ForeignPlant(mach, labels)
        for eta in args.eta:
            rows = {m: run(m, path, prof, plant, args.tol, eta)
                    for m in ("kinematic", "conservative", "pidd")}
            k, c, p = rows["kinematic"], rows["conservative"], rows["pidd"]
            cal = "–"
            try:
                q = run("pidd", path, learned(path, prof, plant, args.tol, eta, tmp), plant,
                        args.tol, eta)
                tail = f"{q.cycle_s:.3f} | {q.rms_gamma_um:.2f} | {q.within:.4f}"
                if args.calibration:
                    cal = calibration(path, learned(path, prof, plant, args.tol, eta, tmp),
                                      plant, args.tol, eta)
            except FeedOptError as exc:  # the learned noise level alone fills the tolerance
                tail = f"refused: {str(exc).split(';')[0]} | – | –"
            lim = 1000 * (1 - eta) * args.tol
            print(f"| {seed} | {mach.kind} | {eta:g} | {k.cycle_s:.3f} | {c.cycle_s:.3f} "
                  f"({c.info.get('conservative_scale', 1.0):.3f}) | {p.cycle_s:.3f} | "
                  f"{p.cycle_s / c.cycle_s:.3f} | {p.rms_gamma_um:.2f} ({lim:.2f}) | "
                  f"{p.within:.4f} | {k.within:.4f} | {tail} |", flush=True)
            if args.calibration:
                print(f"|   | the learned twin on its print: {cal} |", flush=True)
            if args.prints > 1:
                seq, p_k = [], prof
                for k in range(args.prints):
                    r = run("pidd", path, p_k, plant, args.tol, eta)
                    seq.append(f"{r.cycle_s:.2f} s, {r.rms_gamma_um:.2f} µm, {r.within:.4f}")
                    if k + 1 < args.prints:
                        p_k = learned(path, p_k, plant, args.tol, eta, tmp)
                print(f"|   | print after print (cycle, RMS γ, within): {' → '.join(seq)} |",
                      flush=True)


if __name__ == "__main__":
    main()
