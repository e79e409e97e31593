"""How much cycle time any method can win on the butterfly, and how much ours do (issue 5).

For each scenario it prints:

- the **time-optimal bound** of the contour: the shortest traversal of the butterfly NURBS
  (../shared/data/butterfly_nurbs.json) under the scenario's V_max and per-axis A_max alone
  (plan.bound; no contour-error constraint, no junction rule). No method obeying the kinematic
  limits, whatever it knows of the dynamics, can be faster on the contour;
- kinematic, conservative, pidd and oracle run by ``optimize.compare.run_method`` on the same
  plant (the table of ``gcode-feedopt compare``), with their whole-run cycle and the time on
  the extruded contour (the paper's cycle time, without the approach travel);
- the **paper's own baseline**: one trapezoidal feed profile over the whole contour (constant
  feed, tangential acceleration only; Sec. 5's "trapezoidal acceleration profile" with its
  jerk taken as infinite, which only helps it), V_max and A_max scaled down together by
  bisection until RMS γ / E_max ≤ 1 − η on the same plant;
- the largest gain any method could have over conservative, 1 − bound / conservative's
  contour time, next to pidd's gain.

    python benchmarks/bench_paper_gain.py [--scenario issue,binding,nomad3]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

import numpy as np

from gcode_feedopt.optimize.compare import run_method
from gcode_feedopt.optimize.methods import largest_passing_scale, rms_violation_ratio
from gcode_feedopt.pipeline import path_for, read_for
from gcode_feedopt.plan.bound import time_optimal_bound
from gcode_feedopt.plan.curves import nurbs_points
from gcode_feedopt.plan.trapezoid import sample, trapezoids
from gcode_feedopt.profile import load_profile
from gcode_feedopt.vm import effects as fx
from gcode_feedopt.vm.plant import Plant

REPO = pathlib.Path(__file__).resolve().parents[1]
NURBS = REPO.parent / "shared" / "data" / "butterfly_nurbs.json"
GCODE = REPO / "sample_gcode" / "butterfly.gcode"

#: name: (machine, tolerance or None for the profile's, effect spec)
SCENARIOS = {
    "issue": ("ender3pro", 0.1, "sinusoid:axis=x,amp_mm=0.05"),
    "binding": ("ender3pro", 0.05, "sinusoid:axis=x,amp_mm=0.02"),
    "nomad3": ("nomad3", None, "sinusoid:axis=x"),
}
METHODS = ("kinematic", "conservative", "pidd", "oracle")


def rest_to_rest(length: float, v: float, a: float, ts: float) -> np.ndarray:
    """Distance travelled at each sample after the start of a constant-acceleration
    trapezoid over ``length`` (rest to rest; plan.trapezoid, one segment)."""
    if length <= 0:
        return np.zeros(0)
    one = np.ones(1)
    tr = trapezoids(np.zeros(2), length * one, a * one, v * one, np.zeros(1))
    return sample(tr, np.array([0.0, length]), ts)[1:]


def paper_baseline(path, prof, plant, tol, eta):
    """One trapezoid over the contour (travels before/after at full limits, rest between),
    limits scaled like conservative's (methods.largest_passing_scale)."""
    ext = np.flatnonzero(path.de_mm > 0)
    s_a = float(path.s0_mm[ext[0]])
    s_b = float(path.s0_mm[ext[-1]] + path.length_mm[ext[-1]])
    L = float(path.total_length_mm)
    V, A, ts = prof.limits.vmax_mm_s, prof.limits.amax_mm_s2, prof.ts_s

    def run(scale):
        contour = rest_to_rest(s_b - s_a, V * scale, A * scale, ts)
        s = np.concatenate([[0.0], rest_to_rest(s_a, V, A, ts), s_a + contour,
                            s_b + rest_to_rest(L - s_b, V, A, ts)])
        r, m = rms_violation_ratio(path, s, plant, tol, ts)
        return r, (contour.size * ts, m)

    scale, r, (t_contour, met), _ = largest_passing_scale(run, 1.0 - eta, steps=12)
    return scale, (t_contour, r, met)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenario", default=",".join(SCENARIOS))
    a = ap.parse_args()
    pts = nurbs_points(json.loads(NURBS.read_text()))
    for name in a.scenario.split(","):
        machine, tol, effect = SCENARIOS[name]
        prof = load_profile(machine)
        tol = tol or prof.limits.tolerance_mm
        eta = prof.limits.stringency
        V, A = prof.limits.vmax_mm_s, prof.limits.amax_mm_s2
        path = path_for(read_for(GCODE, prof), prof)
        plant = Plant(prof, seed=0, effects=[fx.parse_effect(effect)], nominal=True)
        bound = time_optimal_bound(pts, V, A)
        print(f"\n== {name}: {machine}, V {V:g} mm/s, A {A:g} mm/s², E_max {tol:g} mm, η {eta:g}, {effect}")
        print(f"time-optimal bound of the contour ({bound.length_mm:.1f} mm, kinematic limits only): "
              f"{bound.time_s:.3f} s")
        print(f"{'method':>22}  {'cycle s':>8}  {'contour s':>9}  {'RMS γ µm':>8}  {'within':>7}  {'compute s':>9}")
        rows = {}
        for m in METHODS:
            r = run_method(m, path, prof, plant, tolerance_mm=tol, stringency=eta)
            rows[m] = r
            print(f"{m:>22}  {r.cycle_time_s:8.3f}  {r.contour_time_s:9.3f}  {r.rms_gamma_um:8.2f}  "
                  f"{r.within_fraction:7.4f}  {r.compute_s:9.2f}")
        t0 = time.perf_counter()
        scale, (t_contour, ratio, met) = paper_baseline(path, prof, plant, tol, eta)
        print(f"{'paper baseline':>22}  {'':>8}  {t_contour:9.3f}  {1000 * met.rms_gamma_mm:8.2f}  "
              f"{met.within_fraction:7.4f}  {time.perf_counter() - t0:9.2f}   (limits x {scale:.3f})")
        cons, pidd = rows["conservative"].contour_time_s, rows["pidd"].contour_time_s
        print(f"largest possible gain over conservative on the contour: {100 * (1 - bound.time_s / cons):.1f} %"
              f"; pidd's: {100 * (1 - pidd / cons):.1f} % (cycle: "
              f"{100 * (1 - rows['pidd'].cycle_time_s / rows['conservative'].cycle_time_s):.1f} %)")
        print(f"over the paper's baseline: largest possible {100 * (1 - bound.time_s / t_contour):.1f} %, "
              f"pidd's {100 * (1 - pidd / t_contour):.1f} %; pidd vs oracle (contour): "
              f"{100 * (pidd / rows['oracle'].contour_time_s - 1):+.1f} %")


if __name__ == "__main__":
    main()
