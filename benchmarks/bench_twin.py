"""Cost of the twin per sample: one prediction and one learning update, n2 = 10, n3 = 30.

    python benchmarks/bench_twin.py

Runs AxisTwin.run over 20 s of butterfly motion (10,000 samples at 2 ms) with and without
learning (a warm-up run, then the median of ``REPEATS``), and the pure blr functions in a loop,
and prints µs per sample.
"""

from __future__ import annotations

import pathlib
import time

import numpy as np

from gcode_feedopt.gcode.path import build_path
from gcode_feedopt.gcode.reader import read_file
from gcode_feedopt.plan.kinematic import plan_kinematic
from gcode_feedopt.profile import load_profile
from gcode_feedopt.twin.blr import laplace_update, predict
from gcode_feedopt.twin.model import axis_twin

REPO = pathlib.Path(__file__).resolve().parents[1]
#: timed runs of each (a busy host varies by 2× run to run; the median is what is quoted)
REPEATS = 5


def main():
    prof = load_profile("ender3pro")
    path = build_path(read_file(REPO / "sample_gcode" / "butterfly.gcode"))
    pos = path.position(plan_kinematic(path, prof).s_mm)
    x = np.tile(pos[:, 0], 3)[:10000]
    meas = x + 0.01
    tw = axis_twin(prof, "x")
    d = tw.mu.size
    print(f"n2 = {prof.twin.n2}, n3 = {prof.twin.n3}, {d} features, "
          f"{tw.ir.factor.shape[1]} covariance directions, {x.size} samples")
    for label, meas_k, learn in (("predict only    ", None, False),
                                 ("predict + learn ", meas, True)):
        runs = []
        for _ in range(REPEATS + 1):  # the first run warms caches up and is not counted
            tw = axis_twin(prof, "x")
            t0 = time.perf_counter()
            tw.run(x, meas_k, learn=learn)
            runs.append(1e6 * (time.perf_counter() - t0) / x.size)
        runs = np.array(runs[1:])
        print(f"AxisTwin.run {label}  : {np.median(runs):7.1f} µs/sample median "
              f"(fastest {runs.min():.1f}, slowest {runs.max():.1f}; {REPEATS} runs)")
    rng = np.random.default_rng(0)
    mu, cov = tw.mu, tw.cov
    rows = rng.normal(size=(5000, d))
    var = np.full(d, 1e-4)
    t0 = time.perf_counter()
    for r in rows:
        predict(mu, cov, r, var, 1e-4)
    t1 = time.perf_counter()
    for r in rows:
        mu, cov = laplace_update(mu, cov, r, var, 0.1, 1e-4)
    t2 = time.perf_counter()
    print(f"blr.predict (one sample)       : {1e6 * (t1 - t0) / len(rows):7.1f} µs")
    print(f"blr.laplace_update (one sample): {1e6 * (t2 - t1) / len(rows):7.1f} µs")


if __name__ == "__main__":
    main()
