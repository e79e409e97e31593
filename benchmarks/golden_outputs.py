"""Golden hashes of the writer's output, to show a speed-up changes no byte.

For every real file in ../shared/data/gcode/ and the two sample files, the whole pipeline
(:func:`gcode_feedopt.pipeline.optimize_file`, method kinematic) is run in refeed and in
sampled mode, under ``--speed machine`` and ``--speed slicer``; the sha256 of each output and of its report
(without the wall-clock fields and the output's temporary path) is recorded. Schedules that
are *not* the firmware's own plan are written too, so the writer's general path is covered:

- ``vmax40``: the kinematic plan at V_max 40 mm/s, written with the accelerations of the
  default limits (the plan is still trapezoidal, but slower than the file allows);
- ``dip``: the kinematic plan time-warped so the speed dips by up to 45 % every 3.7 s
  (the dips fall anywhere inside moves, so many moves need more than one line).

    python benchmarks/golden_outputs.py --out /tmp/golden_before.json     # record
    python benchmarks/golden_outputs.py --check /tmp/golden_before.json   # compare

``--small`` runs only the small files (a minute instead of many); ``--sampled-big`` adds
sampled mode on the real slicer files. Exit status 1 if any hash differs from the ``--check``
file.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import pathlib
import sys
import tempfile
import time

import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]
GCODE_DIR = REPO.parent / "shared" / "data" / "gcode"
#: files run in every mode and on both built-in machines; the others (the real slicer files)
#: run on ender3pro, sampled mode only with --sampled-big (a sampled output has one line per
#: 2 ms of print: 1.6 M lines for the square tower, minutes per run)
SMALL = ("butterfly", "part_prusaslicer")

#: report fields that are wall-clock or temporary paths, not results
VOLATILE = ("stage_wall_s", "output", "input")


def files() -> dict[str, pathlib.Path]:
    out = {p.stem: p for p in sorted(GCODE_DIR.glob("*.gcode"))}
    out["butterfly"] = REPO / "sample_gcode" / "butterfly.gcode"
    out["part_prusaslicer"] = REPO / "sample_gcode" / "part_prusaslicer.gcode"
    return out


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def pipeline_case(src: pathlib.Path, machine: str, **opts) -> dict:
    from gcode_feedopt.pipeline import Options, optimize_file
    from gcode_feedopt.profile import load_profile

    profile = load_profile(machine)
    with tempfile.TemporaryDirectory() as tmp:
        out = pathlib.Path(tmp) / "out.gcode"
        rep = optimize_file(src, out, profile, Options(method="kinematic", **opts))
        data = out.read_bytes()
    d = rep.to_dict()
    for k in VOLATILE:
        d.pop(k, None)
    return {"output": sha(data), "report": sha(json.dumps(d, sort_keys=True, default=float).encode()),
            "bytes": len(data)}


def dip_schedule(sched, period_s: float = 3.7, depth: float = 0.45):
    """``sched`` time-warped: the path is followed at w(τ) times the planned rate, with
    w = 1 − depth·max(0, sin 2πτ/period)^4 (dips of ``depth`` every ``period_s``)."""
    from gcode_feedopt.gcode.schedule import Schedule

    ts = sched.ts_s
    s = sched.s_mm
    tau = np.arange(s.size) * ts
    w = 1.0 - depth * np.maximum(0.0, np.sin(2 * np.pi * tau / period_s)) ** 4
    # new time at each original sample: t'(τ) = ∫ dτ / w
    t_new = np.concatenate([[0.0], np.cumsum(0.5 * (1 / w[1:] + 1 / w[:-1]) * ts)])
    k = int(np.ceil(t_new[-1] / ts)) + 1
    tau_k = np.interp(np.arange(k) * ts, t_new, tau)
    s_new = np.maximum.accumulate(np.interp(tau_k, tau, s))
    s_new[-1] = s[-1]
    return Schedule(ts_s=ts, s_mm=s_new, method="dip", info={})


def schedule_cases(src: pathlib.Path, machine: str, modes=("refeed", "sampled")) -> dict:
    """Write perturbed schedules directly (writer + verify), hashing bytes and tags."""
    from gcode_feedopt.gcode.verify import verify
    from gcode_feedopt.gcode.writer import write
    from gcode_feedopt.pipeline import path_for, read_for
    from gcode_feedopt.plan.kinematic import plan_kinematic, writer_accel
    from gcode_feedopt.profile import load_profile
    from gcode_feedopt import firmware

    profile = load_profile(machine)
    fw = profile.firmware
    program = read_for(src, profile)
    path = path_for(program, profile)
    fw_limits = firmware.move_limits(program, profile)
    acc = writer_accel(path, profile, fw_limits)
    base = plan_kinematic(path, profile, fw_limits=fw_limits)
    scheds = {"vmax40": plan_kinematic(path, profile, vmax_mm_s=40.0, fw_limits=fw_limits),
              "dip": dip_schedule(base)}
    out = {}
    for name, sched in scheds.items():
        for mode in modes:
            res = write(program, path, sched, profile, mode=mode, accel_mm_s2=acc)
            verify(program, res, flavour=fw.flavour, g91_relative_e=fw.g91_relative_e)
            out[f"{name}/{mode}"] = {"output": sha(res.data), "tags": sha(repr(res.tags).encode()),
                                     "bytes": len(res.data), "sub_moves": res.sub_moves}
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=pathlib.Path, help="write the hashes here (JSON)")
    ap.add_argument("--check", type=pathlib.Path, help="compare with these hashes")
    ap.add_argument("--small", action="store_true", help="small files only")
    ap.add_argument("--sampled-big", action="store_true",
                    help="sampled mode on the real slicer files too (slow)")
    ap.add_argument("--only", help="run only files whose name contains this")
    a = ap.parse_args()
    want = json.loads(a.check.read_text()) if a.check else None
    got = {}
    bad = 0

    def record(key, val):
        nonlocal bad
        got[key] = val
        ref = None if want is None else want.get(key)
        status = "" if want is None else ("ok" if ref == val else
                                          ("MISSING" if ref is None else "DIFFERENT"))
        if status in ("DIFFERENT",):
            bad += 1
        print(f"{key:<60} {val['output']} {val.get('report', val.get('tags'))} {status}",
              flush=True)
        if a.out:  # after every case: a long run that dies keeps what it has
            a.out.write_text(json.dumps(got, indent=1, sort_keys=True))

    for stem, src in files().items():
        small = stem in SMALL
        if (a.small and not small) or (a.only and a.only not in stem):
            continue
        machines = ("ender3pro", "nomad3") if small else ("ender3pro",)
        for machine in machines:
            t0 = time.perf_counter()
            record(f"{stem}/{machine}/refeed",
                   pipeline_case(src, machine, mode="refeed", speed="machine"))
            record(f"{stem}/{machine}/refeed+slicer",
                   pipeline_case(src, machine, mode="refeed", speed="slicer"))
            if small or a.sampled_big:
                record(f"{stem}/{machine}/sampled",
                       pipeline_case(src, machine, mode="sampled", speed="machine"))
                if small or "arcs" not in stem:
                    # the arc file sampled at the slicer's feeds: 20+ GB in the untouched
                    # code (millions of sub-arcs through the firmware model); left out
                    record(f"{stem}/{machine}/sampled+slicer",
                           pipeline_case(src, machine, mode="sampled", speed="slicer"))
            modes = ("refeed", "sampled") if small or a.sampled_big else ("refeed",)
            for k, v in schedule_cases(src, machine, modes).items():
                record(f"{stem}/{machine}/{k}", v)
            print(f"  ({stem} on {machine}: {time.perf_counter() - t0:.0f} s)", flush=True)
    if want is not None:
        missing = [k for k in got if k not in want]
        print(f"{len(got) - bad - len(missing)} equal, {bad} different, {len(missing)} not in "
              f"{a.check}")
        sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
