"""Speed of the virtual machine, by stage, and the ratio to the print it simulates.

    python benchmarks/bench_simulate.py                       # every file in ../shared/data/gcode
    python benchmarks/bench_simulate.py FILE.gcode --machine ender3pro --effect sinusoid:axis=x
    python benchmarks/bench_simulate.py --synthetic 2700000    # plant/metrics/log only, no G-code

Target (issue 4): the whole `simulate` at least 100x faster than the print it simulates
(ratio = simulated cycle time / wall-clock seconds of read + firmware + plant + metrics + log).
The log is written to a temporary file and measured; `np.savetxt` on the same rows is timed on
a 200,000-row slice for comparison (`--no-savetxt` skips it).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile
import time

import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]
GCODE_DIR = REPO.parent / "shared" / "data" / "gcode"


def bench_log(tr, out, tmp: pathlib.Path, savetxt: bool) -> dict:
    from gcode_feedopt.vm.log import read_log, write_log

    res = {}
    t0 = time.perf_counter()
    write_log(tmp, tr.t_s, tr.pos_mm, out.measured_mm, tr.e_mm)
    res["log_write"] = time.perf_counter() - t0
    res["log_mb"] = tmp.stat().st_size / 1e6
    t0 = time.perf_counter()
    read_log(tmp)
    res["log_read"] = time.perf_counter() - t0
    if savetxt:
        n = min(200_000, tr.n_samples)
        data = np.column_stack([tr.t_s[:n], tr.pos_mm[:n, :2], out.measured_mm[:n, :2],
                                tr.pos_mm[:n, 2], out.measured_mm[:n, 2], tr.e_mm[:n]])
        t0 = time.perf_counter()
        np.savetxt(tmp.with_suffix(".savetxt"), data, fmt="%.6f", delimiter=",")
        res["savetxt_per_row_us"] = (time.perf_counter() - t0) / n * 1e6
        res["log_write_per_row_us"] = res["log_write"] / tr.n_samples * 1e6
        tmp.with_suffix(".savetxt").unlink()
    tmp.unlink()
    return res


def synthetic(K: int, seed: int = 0):
    """A K-sample zig-zag at 50 mm/s (new direction every 0.1 s), extruding."""
    from gcode_feedopt.vm.trajectory import Trajectory

    rng = np.random.default_rng(seed)
    ts = 0.002
    ang = np.repeat(rng.uniform(0, 2 * np.pi, K // 50 + 1), 50)[:K]
    xy = 100 + np.cumsum(50 * ts * np.column_stack([np.cos(ang), np.sin(ang)]), axis=0)
    return Trajectory(ts, np.column_stack([xy, np.zeros(K)]), np.arange(K) * 0.01)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("files", nargs="*", type=pathlib.Path)
    ap.add_argument("--machine", default="ender3pro")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--effect", action="append", default=[])
    ap.add_argument("--synthetic", type=int, metavar="K", help="plant/metrics/log on K synthetic samples")
    ap.add_argument("--no-savetxt", action="store_true")
    args = ap.parse_args(argv)

    from gcode_feedopt.vm import effects as fx

    effects = [fx.parse_effect(s) for s in args.effect]
    tmpdir = pathlib.Path(tempfile.mkdtemp(prefix="bench_simulate_"))

    if args.synthetic:
        sys.path.insert(0, str(REPO / "tests" / "vm"))
        from vm_helpers import step_invariant_impulse

        from gcode_feedopt.vm import metrics
        from gcode_feedopt.vm.plant import Plant

        tr = synthetic(args.synthetic, args.seed)
        h = step_invariant_impulse(2 * np.pi * 40, 0.1, 300)
        t0 = time.perf_counter()
        out = Plant.from_impulse(tr.ts_s, {"x": h, "y": h}, effects, args.seed).simulate(tr)
        t_plant = time.perf_counter() - t0
        t0 = time.perf_counter()
        metrics.evaluate(tr, out.actual_mm, 0.1)
        t_metrics = time.perf_counter() - t0
        lg = bench_log(tr, out, tmpdir / "log.csv", not args.no_savetxt)
        total = t_plant + t_metrics + lg["log_write"]
        print(f"synthetic K={tr.n_samples} ({tr.duration_s:.0f} s of motion, 300 taps): plant {t_plant:.3f} s, "
              f"metrics {t_metrics:.3f} s, log write {lg['log_write']:.3f} s ({lg['log_mb']:.0f} MB), "
              f"log read {lg['log_read']:.3f} s; ratio {tr.duration_s / total:.0f}x")
        if "savetxt_per_row_us" in lg:
            print(f"  log write {lg['log_write_per_row_us']:.2f} us/row vs np.savetxt "
                  f"{lg['savetxt_per_row_us']:.2f} us/row")
        return

    from gcode_feedopt.simulation import simulate_file
    from gcode_feedopt.profile import load_profile

    profile = load_profile(args.machine)
    files = args.files or sorted(GCODE_DIR.glob("*.gcode"))
    print(f"machine {profile.name}, seed {args.seed}, effects {[e.to_spec() for e in effects]}")
    print(f"{'file':42s} {'samples':>9s} {'print s':>9s} {'read':>7s} {'firmw':>7s} {'plant':>7s} "
          f"{'metric':>7s} {'log':>7s} {'wall s':>8s} {'ratio':>7s}")
    for path in files:
        res = simulate_file(path, profile, seed=args.seed, effects=effects)
        lg = bench_log(res.trajectory, res.output, tmpdir / "log.csv", False)
        tm = res.timings_s
        wall = sum(tm.values()) + lg["log_write"]
        print(f"{path.name[:42]:42s} {res.trajectory.n_samples:9d} {res.metrics.cycle_time_s:9.1f} "
              f"{tm['read']:7.2f} {tm['firmware']:7.2f} {tm['plant']:7.2f} {tm['metrics']:7.2f} "
              f"{lg['log_write']:7.2f} {wall:8.2f} {res.metrics.cycle_time_s / wall:6.0f}x")


if __name__ == "__main__":
    main()
