"""What `diagnose` costs: seconds per log on benchA and on foreign machines (one process).

Builds each data set's profile from its FRFs (as benchmarks/independent.py does), then times
``diagnose_log`` over every log of the set: the first pass (modal fits of the extended
profiles, the catalogue's moved and loaded responses computed) and a second over the same
logs (what a batch of logs against one profile costs per log once those are cached).
benchA is read from ../shared/data/independent/; the foreign machines are drawn by
tests/foreign/machines.py (seed 900: a PID servo on a lead screw, its effects including a
heavier table, a friction through the loop and a coupling; seed 1: belt + hotend; seed 0: a
corexy).

    python benchmarks/bench_diagnose.py                    # benchA, foreign 900, 1, 0
    python benchmarks/bench_diagnose.py --seeds 905 --no-bench-a
"""

from __future__ import annotations

import argparse
import pathlib
import statistics
import sys
import tempfile
import time
import warnings

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "benchmarks")]

from independent import DATA, bench_a_profile, encoder_log  # noqa: E402
from tests.foreign.machines import make_machine, write_dataset  # noqa: E402

from gcode_feedopt.closedloop.diagnose import diagnose_log  # noqa: E402


def time_set(data: pathlib.Path, name: str) -> dict:
    """Profile build and two passes of diagnose_log over the set's logs, seconds."""
    t0 = time.perf_counter()
    prof = bench_a_profile(data, name)
    build = time.perf_counter() - t0
    logs = [encoder_log(f.name, data, prof) for f in sorted((data / "logs").glob("log_*.csv"))]
    passes = []
    for _ in range(2):
        per = []
        for log in logs:
            t0 = time.perf_counter()
            diagnose_log(log, prof)
            per.append(time.perf_counter() - t0)
        passes.append(per)
    return {"name": name, "n": len(logs), "build": build, "passes": passes}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[900, 1, 0],
                    help="foreign machines (tests/foreign/machines.py) to time besides benchA")
    ap.add_argument("--no-bench-a", action="store_true", help="foreign machines only")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    sets = [] if args.no_bench_a else [(DATA, "benchA")]
    base = pathlib.Path(tempfile.mkdtemp(prefix="bench-diagnose-"))
    for seed in args.seeds:
        mach = make_machine(seed)
        out = base / f"foreign-{seed}"
        write_dataset(mach, out, effects=True)
        sets.append((out, f"foreign {seed} ({mach.kind})"))
    print("| data set | logs | profile build s | first pass s (median per log) "
          "| second pass s (median per log) |")
    print("| --- | --- | --- | --- | --- |")
    for data, name in sets:
        r = time_set(data, name)
        p1, p2 = r["passes"]
        print(f"| {r['name']} | {r['n']} | {r['build']:.1f} | {sum(p1):.1f} "
              f"({statistics.median(p1):.2f}) | {sum(p2):.1f} ({statistics.median(p2):.2f}) |",
              flush=True)


if __name__ == "__main__":
    main()
