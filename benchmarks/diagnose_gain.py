"""Diagnose → extend the profile → optimize: the gain on the virtual machine (issue 6, item 3).

A nominal ender3pro plant with one hidden linear effect runs a 300-line piece of the butterfly
(kinematic plan) and logs it; diagnose names the effect from that log; the effect is folded
into the profile's FRFs (closedloop.extend); then the same piece is optimized with the twin
method ``pb`` (the twin as the profile states it, no online learning, so the profile is all
it knows) from the original and from the extended profile, each run on the same plant.

    python benchmarks/diagnose_gain.py [--effect delay:axis=x,delay_s=0.008] [--method pb]
"""

from __future__ import annotations

import argparse
import pathlib
import tempfile
import time

import numpy as np

from gcode_feedopt.closedloop.diagnose import diagnose_arrays
from gcode_feedopt.twin.physics import axis_physics
from gcode_feedopt.closedloop.extend import extend_profile
from gcode_feedopt.optimize.compare import run_method
from gcode_feedopt.pipeline import path_for, read_for
from gcode_feedopt.profile import load_profile
from gcode_feedopt.vm import effects as fx
from gcode_feedopt.vm.plant import Plant

REPO = pathlib.Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--effect", default="delay:axis=x,delay_s=0.008")
    ap.add_argument("--method", default="pb")
    ap.add_argument("--lines", type=int, default=300)
    ap.add_argument("--tolerance", type=float, default=0.1)
    a = ap.parse_args()
    prof = load_profile("ender3pro")
    lines = (REPO / "sample_gcode" / "butterfly.gcode").read_bytes().splitlines(keepends=True)
    piece = pathlib.Path(tempfile.mkdtemp()) / "piece.gcode"
    piece.write_bytes(b"".join(lines[:a.lines]))
    path = path_for(read_for(piece, prof), prof)
    hidden = fx.parse_effect(a.effect)
    plant = Plant(prof, seed=0, nominal=True,
                  effects=[hidden, fx.SensorNoise("x", std_mm=0.001), fx.SensorNoise("y", std_mm=0.001)])
    # 1. print with the kinematic plan, log
    run0 = run_method("kinematic", path, prof, plant, tolerance_mm=a.tolerance, stringency=0.95)
    from gcode_feedopt.optimize.methods import plan_schedule
    from gcode_feedopt.optimize.methods import vm_trajectory
    sched = plan_schedule("kinematic", path, prof, tolerance_mm=a.tolerance, stringency=0.95)
    tr = vm_trajectory(path, sched.s_mm, sched.ts_s)
    meas = plant.simulate(tr).measured_mm
    # 2. diagnose
    d = diagnose_arrays(tr.pos_mm, meas, prof.ts_s, axis_physics(prof))
    print(f"hidden: {hidden.to_dict()}")
    print(f"named:  {d.effects}")
    print(f"held-out RMS before/after: {d.holdout_rms_mm}")
    ext = extend_profile(prof, d.effects, source="benchmarks/diagnose_gain.py")
    # 3. optimize from both profiles on the same plant
    print(f"\n{'profile':10s} {'method':8s} {'cycle s':>8s} {'RMS viol µm':>12s} {'within':>7s} "
          f"{'max err mm':>10s} {'pred RMS x/y µm':>16s} {'compute s':>9s}")
    print(f"{'-':10s} {'kinematic':8s} {run0.cycle_time_s:8.3f} {run0.rms_gamma_um:12.2f} "
          f"{run0.within_fraction:7.3f} {run0.max_contour_error_mm:10.4f}")
    for name, p in (("original", prof), ("extended", ext)):
        t0 = time.perf_counter()
        r = run_method(a.method, path, p, plant, tolerance_mm=a.tolerance, stringency=0.95,
                       online=False)
        pr = r.prediction_rms_mm
        prs = f"{pr['x'] * 1e3:.1f}/{pr['y'] * 1e3:.1f}" if pr else "-"
        print(f"{name:10s} {a.method:8s} {r.cycle_time_s:8.3f} {r.rms_gamma_um:12.2f} "
              f"{r.within_fraction:7.3f} {r.max_contour_error_mm:10.4f} {prs:>16s} "
              f"{time.perf_counter() - t0:9.1f}")


if __name__ == "__main__":
    main()
