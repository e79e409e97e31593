"""HiGHS vs OSQP on the same window problems (issue 5: choose the solver by measurement).

Runs pidd (offline, one process) over the first LINES lines of a file (default the butterfly)
with each solver and prints window count, LP solves, solve rate (optimal / solves), solver
seconds, mean and p95 time per solve, and the cycle time reached.

    python benchmarks/bench_window_solvers.py [--lines 600] [--file PATH] [--solvers highs,osqp]
"""

from __future__ import annotations

import argparse
import pathlib
import tempfile
import time

import numpy as np

from gcode_feedopt.errors import FeedOptError
from gcode_feedopt.optimize import MpcSettings
from gcode_feedopt.optimize.methods import make_twin_predictor, plan_mpc
from gcode_feedopt.pipeline import path_for, read_for
from gcode_feedopt.profile import load_profile

REPO = pathlib.Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--lines", type=int, default=600)
    ap.add_argument("--machine", default="ender3pro")
    ap.add_argument("--file", default=str(REPO / "sample_gcode" / "butterfly.gcode"))
    ap.add_argument("--solvers", default="highs,osqp")
    a = ap.parse_args()
    prof = load_profile(a.machine)
    lines = pathlib.Path(a.file).read_bytes().splitlines(keepends=True)
    tmp = pathlib.Path(tempfile.mkdtemp()) / "piece.gcode"
    tmp.write_bytes(b"".join(lines[:a.lines]))
    path = path_for(read_for(tmp, prof), prof)
    print(f"{pathlib.Path(a.file).name}, first {a.lines} lines, {a.machine}, pidd offline, E_max "
          f"{prof.limits.tolerance_mm} mm, η {prof.limits.stringency}")
    print(f"{'solver':>7} {'windows':>8} {'LPs':>6} {'LP ok %':>8} {'solver s':>9} "
          f"{'mean ms':>8} {'p95 ms':>7} {'cycle s':>8} {'wall s':>7}")
    for solver in a.solvers.split(","):
        pred = make_twin_predictor(prof, "pidd", learn=False)
        t0 = time.perf_counter()
        try:
            s = plan_mpc(path, prof, pred, method="pidd", tolerance_mm=prof.limits.tolerance_mm,
                         stringency=prof.limits.stringency, settings=MpcSettings(solver=solver),
                         workers=1)
        except FeedOptError as exc:
            print(f"{solver:>7} failed after {time.perf_counter() - t0:.1f} s: {exc}")
            continue
        wall = time.perf_counter() - t0
        info = s.info
        times = np.asarray(info.get("_solve_times_s", []) or [0.0])
        n_lp = info["solver_iterations"]
        bad = info.get("lp_failed", 0) + info.get("lp_infeasible", 0)
        print(f"{solver:>7} {info['windows']:>8} {n_lp:>6} {100 * (n_lp - bad) / max(n_lp, 1):>8.1f} "
              f"{info['solver_s']:>9.2f} {1000 * times.mean():>8.2f} "
              f"{1000 * np.quantile(times, 0.95):>7.2f} {s.duration_s:>8.3f} {wall:>7.2f}")


if __name__ == "__main__":
    main()
