"""Whole-pipeline benchmark (issue 9): per-stage wall time and peak memory per case.

Cases: the Cura Benchy (95,520 moves), the Benchy repeated 2x and 4x (whole files
concatenated: each copy homes and heats again, which the reader accepts), the butterfly, and
(``arcwelder``, not in the default list: minutes) the ArcWelder Benchy, whose 11.6 h at its
cooling speeds are 20.6 M samples of plan.
Each case runs `gcode-feedopt` in a fresh process (`--dry-run --report`), so the peak RSS is
that run's own (resource.getrusage of the child).

    python benchmarks/bench_pipeline.py [--method kinematic] [--cases benchy,benchy2,benchy4,butterfly]
    python benchmarks/bench_pipeline.py --method pidd --cases arcwelder
    python benchmarks/bench_pipeline.py --write   # also write benchmarks/RESULTS.md
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import platform
import subprocess
import sys
import tempfile
import time

REPO = pathlib.Path(__file__).resolve().parents[1]
BENCHY = REPO.parent / "shared" / "data" / "gcode" / "cura-4.11_ender3_3dbenchy.gcode"
STAGES = ("parse", "path", "plan", "write", "verify", "firmware", "execute")


def case_files(tmp: pathlib.Path) -> dict[str, pathlib.Path]:
    data = BENCHY.read_bytes()
    out = {"benchy": BENCHY, "butterfly": REPO / "sample_gcode" / "butterfly.gcode",
           "arcwelder": BENCHY.parent / "slic3rpe-arcwelder_3dbenchy-arcs.gcode"}
    for k in (2, 4):
        p = tmp / f"benchy_x{k}.gcode"
        p.write_bytes(data * k)
        out[f"benchy{k}"] = p
    return out


#: the child reports its own peak RSS at exit (click ends with sys.exit; atexit still runs)
CHILD = ("import atexit, resource, runpy, sys\n"
         "atexit.register(lambda: sys.stderr.write("
         "'PEAK_KB=%d\\nPEAK_CHILD_KB=%d\\n' % (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, "
         "resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)))\n"
         "sys.argv = ['gcode-feedopt'] + sys.argv[1:]\n"
         "runpy.run_module('gcode_feedopt', run_name='__main__')\n")


def run_case(path: pathlib.Path, method: str, machine: str) -> dict:
    rep = pathlib.Path(tempfile.mkdtemp()) / "r.json"
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", CHILD, str(path), "--machine", machine,
                        "--method", method, "--dry-run", "--report", str(rep)],
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"{path.name}: {r.stderr.strip()}")
    def peak(tag):
        return max((int(x.split("=")[1]) for x in r.stderr.splitlines() if x.startswith(tag)),
                   default=0)

    peak_kb = peak("PEAK_KB=")
    child_kb = peak("PEAK_CHILD_KB=")
    d = json.loads(rep.read_text())
    return {"moves": d["moves"], "wall_s": wall, "stages": d["stage_wall_s"],
            "print_s": d["output_time_s"], "peak_mb": peak_kb / 1024.0,
            "worker_mb": child_kb / 1024.0, "workers": d.get("extra", {}).get("parallel_workers", 0),
            "plan_s": d.get("plan_time_s"), "pred_max": d.get("predicted_max_contour_error_mm"),
            "executed": d.get("extra", {}).get("executed"), "input_s": d.get("input_time_s"),
            "as_sliced_s": d["input_time_s"]}


def machine_text() -> str:
    cpu = "unknown CPU"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2 ** 30
    import numpy

    return (f"{cpu}, {os.cpu_count()} cores, {mem:.0f} GiB RAM, Python {platform.python_version()}, "
            f"numpy {numpy.__version__}, {platform.system()} {platform.release()}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--method", default="kinematic")
    ap.add_argument("--machine", default="ender3pro")
    ap.add_argument("--cases", default="benchy,benchy2,benchy4,butterfly")
    ap.add_argument("--write", action="store_true", help="write benchmarks/RESULTS.md")
    a = ap.parse_args()
    tmp = pathlib.Path(tempfile.mkdtemp())
    files = case_files(tmp)
    rows = {}
    head = f"{'case':<10} {'moves':>8} {'wall s':>7} " + " ".join(f"{s:>8}" for s in STAGES) + \
        f" {'peak MB':>8} {'worker MB':>9} {'x print':>8} {'x sliced':>8}"
    lines = [f"method {a.method}, machine {a.machine}; {machine_text()}", head]
    print(lines[0])
    print(head)
    for name in a.cases.split(","):
        r = run_case(files[name], a.method, a.machine)
        rows[name] = r
        line = (f"{name:<10} {r['moves']:>8} {r['wall_s']:>7.2f} "
                + " ".join(f"{r['stages'].get(s, 0.0):>8.2f}" for s in STAGES)
                + f" {r['peak_mb']:>8.0f} {r['worker_mb']:>9.0f} {r['print_s'] / r['wall_s']:>7.0f}x"
                + f" {r['as_sliced_s'] / r['wall_s']:>7.0f}x")
        print(line, flush=True)
        lines.append(line)
    for name, r in rows.items():
        ex = r.get("executed")
        if ex and r.get("pred_max") is not None:
            line = (f"{name}: print {r['input_s']:.0f} s as sliced -> plan {r['plan_s']:.1f} s, "
                    f"predicted worst {r['pred_max']:.3f} mm; executed (firmware model, nominal "
                    f"plant) {ex['time_s']:.1f} s, worst {ex['max_contour_error_mm']:.3f} mm, "
                    f"{100 * ex['within_fraction']:.2f} % within")
            print(line)
            lines.append(line)
    if "benchy" in rows and "benchy4" in rows:
        ratio = rows["benchy4"]["wall_s"] / rows["benchy"]["wall_s"]
        msg = f"scaling: 4x file takes {ratio:.2f}x the time of 1x (target <= 4.5)"
        print(msg)
        lines.append(msg)
    if a.write:
        write_results(a.method, lines)


def write_results(method: str, lines: list[str]) -> None:
    """Replace (or add) this method's section of benchmarks/RESULTS.md."""
    out = REPO / "benchmarks" / "RESULTS.md"
    head = "# Pipeline benchmark results\n\n"
    text = out.read_text() if out.exists() else head
    if not text.startswith(head):
        text = head + text
    tag = f"## method {method}\n"
    section = (tag + f"\n`python benchmarks/bench_pipeline.py --method {method} --write` "
               f"({time.strftime('%Y-%m-%d')}); seconds of wall time per stage, peak RSS of the "
               "run's process and of its largest worker process (offline twin methods plan "
               "exact-stop chunks in forked workers; their pages are shared copy-on-write with "
               "the parent, so parent + workers × worker is an upper bound), and how many times "
               "faster than the print the run is (x print: the written file's print time, x sliced: the "
               "file as sliced, both by the firmware model).\n\n```\n" + "\n".join(lines) + "\n```\n\n")
    body = text[len(head):]
    parts = body.split("## method ")
    kept = [p for p in parts if p.strip() and not p.startswith(f"{method}\n")]
    # a section written before sections had headers: keep it under its method's header
    for i, p in enumerate(kept):
        if not p.split("\n", 1)[0].strip().isidentifier():
            m = "kinematic" if "--method kinematic" in p else "unknown"
            kept[i] = "" if m == method else f"{m}\n\n{p.strip()}\n\n"
    kept = [p for p in kept if p]
    new = head + section + "".join("## method " + p for p in kept)
    out.write_text(new)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
