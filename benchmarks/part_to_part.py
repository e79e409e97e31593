"""Part to part on the virtual machine (issue 6, item 2): print → log → learn → print, 5 rounds.

One machine (ender3pro FRF draw, seed 2) with a hidden 3 ms X delay prints a 300-line piece
of the butterfly. Each round plans with ``--method`` from the current profile as `optimize`
does (offline: what the profile learned is all the twin knows), runs that plan on the
machine, writes the encoder log, and ``learn``s the profile from it (closedloop.learn: bounded
update). Printed per round: the twin's open-loop prediction RMS on that print (before
learning from it), RMS tolerance violation, fraction within tolerance, cycle time, and what
learn wrote per axis (step scale, level at rest σ_r, speed part k_v, the RMS of the residual
filter on that print: docs/twin.md §7).
(benchmarks/closed_loop.py is the same loop with a fan of random phase.)

    python benchmarks/part_to_part.py [--rounds 5] [--method pidd] [--effect SPEC]
"""

from __future__ import annotations

import argparse
import pathlib
import tempfile

import numpy as np

from gcode_feedopt.closedloop.learn import learn_logs
from gcode_feedopt.closedloop.logs import load_log
from gcode_feedopt.optimize.methods import plan_schedule, vm_trajectory
from gcode_feedopt.pipeline import path_for, read_for
from gcode_feedopt.profile import load_profile
from gcode_feedopt.vm import effects as fx
from gcode_feedopt.vm.log import write_log
from gcode_feedopt.vm.metrics import evaluate
from gcode_feedopt.vm.plant import Plant

REPO = pathlib.Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--method", default="pidd")
    ap.add_argument("--effect", default="delay:axis=x,delay_s=0.003")
    ap.add_argument("--lines", type=int, default=300)
    ap.add_argument("--seed", type=int, default=2)
    a = ap.parse_args()
    prof = load_profile("ender3pro")
    tmp = pathlib.Path(tempfile.mkdtemp())
    lines = (REPO / "sample_gcode" / "butterfly.gcode").read_bytes().splitlines(keepends=True)
    piece = tmp / "piece.gcode"
    piece.write_bytes(b"".join(lines[:a.lines]))
    path = path_for(read_for(piece, prof), prof)
    plant = Plant(prof, seed=a.seed, effects=[fx.parse_effect(a.effect),
                                               fx.SensorNoise("x", std_mm=0.001),
                                               fx.SensorNoise("y", std_mm=0.001)])
    print(f"machine: ender3pro draw seed {a.seed} + {a.effect}; method {a.method}, "
          f"{a.lines} butterfly lines, tolerance 0.1 mm")
    print(f"{'round':>5s} {'pred RMS x µm':>13s} {'pred RMS y µm':>13s} {'RMS viol µm':>11s} "
          f"{'within':>7s} {'cycle s':>8s}  learned")
    for k in range(1, a.rounds + 1):
        # the plan `optimize` writes (the offline slow-down optimizer), run, logged, learned
        sched = plan_schedule(a.method, path, prof, tolerance_mm=0.1, stringency=0.95, plant=plant)
        tr = vm_trajectory(path, sched.s_mm, sched.ts_s)
        out = plant.simulate(tr)
        m = evaluate(tr, out.actual_mm, 0.1)
        log_path = tmp / f"round{k}.csv"
        write_log(log_path, tr.t_s, tr.pos_mm, out.measured_mm, tr.e_mm)
        prof, recs = learn_logs(prof, [load_log(log_path, prof)])
        pr = {q["axis"]: q["prediction_rms_mm"]["before"] for q in recs}
        steps = ", ".join(f"{q['axis']} x{q['step_scale']:.2g} σ_r {q['noise_level_mm'] * 1e3:.1f} µm "
                          f"k_v {q['noise_per_speed_s'] * 1e3:.2f} ms "
                          f"filter {q.get('residual_filter_log_rms_mm', 0.0) * 1e3:.1f} µm"
                          for q in recs)
        print(f"{k:5d} {pr.get('x', np.nan) * 1e3:13.1f} {pr.get('y', np.nan) * 1e3:13.1f} "
              f"{m.rms_gamma_mm * 1e3:11.2f} {m.within_fraction:7.3f} {m.cycle_time_s:8.3f}  {steps}")


if __name__ == "__main__":
    main()
