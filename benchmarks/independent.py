"""The twin and the diagnosis on benchA, a machine simulated apart from this project
(issue 19's benchmark). Reads ../shared/data/independent/ (never copied).

For every benchA log: the truth (labels.json), the diagnosis, the parameter error, the held-out
RMS before / after (the twin's mean with the profile as is / with the profile ``diagnose -o``
writes), and the coverage of the 95 % interval as ``predict`` ships it, without and with
learning (after a log's warm-up). Then the coverage pooled over plants drawn from the profile's
spread, as the optimizer's chance constraint assumes it.

    python benchmarks/independent.py            # ~1–2 min on 2 cores

The end-to-end optimizer figures on a benchA-built plant are in benchmarks/end_to_end.py.
"""

from __future__ import annotations

import json
import pathlib
import sys
import time
import warnings

import numpy as np

from gcode_feedopt.closedloop.diagnose import diagnose_log
from gcode_feedopt.closedloop.logs import MotionLog, log_warmup
from gcode_feedopt.profile import load_profile
from gcode_feedopt.profile.build import build_from_frfs
from gcode_feedopt.twin.model import axis_twin
from gcode_feedopt.twin.physics import draw_impulses
from gcode_feedopt.vm.plant import respond

REPO = pathlib.Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "independent"
Z95 = 1.959964
#: the parameter that sizes each kind (labels.json's names)
KEY = {"delay": "seconds", "backlash": "magnitude_mm", "friction": "magnitude_mm",
       "periodic_time": "amplitude_mm", "periodic_position": "wavelength_mm",
       "resonance_shift": "frequency_hz", "gain": "scale", "cross_coupling": "mm_per_mm_s2"}


def bench_a_profile():
    frf = DATA / "frf"
    prof, _ = build_from_frfs(load_profile("ender3pro"),
                              {a: sorted(frf.glob(f"{a}_*.csv")) for a in "xy"}, name="benchA")
    return prof


def read(name):
    a = np.loadtxt(DATA / "logs" / name, delimiter=",", skiprows=1)
    cmd = np.column_stack([a[:, 1:3], np.zeros(len(a))])
    pos = np.column_stack([a[:, 3:5], np.zeros(len(a))])
    return cmd, pos


def coverage(prof, cmd, pos, w0, learn):
    """% of samples (after the warm-up) inside the 95 % interval, per axis, as predict runs."""
    out = []
    for i, ax in enumerate("xy"):
        mean, std = axis_twin(prof, ax).run(cmd[:, i], pos[:, i], learn=learn, warmup=w0)
        out.append(100 * np.mean(np.abs(pos[w0:, i] - mean[w0:]) <= Z95 * std[w0:]))
    return out


def describe(effects):
    if not effects or all(e["kind"] == "none" for e in effects):
        return "none"
    parts = []
    for e in effects:
        if e["kind"] == "none":
            continue
        k = KEY[e["kind"]]
        v = e["params"][k]
        tie = " (tie: backlash)" if "tie" in e["params"] else ""
        parts.append(f"{e['kind']} {e['axis']} {k}={v:.5g}{tie}")
    return "; ".join(parts)


def param_error(truth, got):
    errs = []
    for t in truth:
        if t["kind"] == "none":
            continue
        g = next((g for g in got if g["kind"] == t["kind"] and g["axis"] == t["axis"]), None)
        if g is None:
            errs.append("missed")
            continue
        k = KEY[t["kind"]]
        tv, gv = t["params"][k], g["params"][k]
        if t["kind"] == "gain":
            tv, gv = tv - 1, gv - 1
        errs.append(f"{100 * (gv - tv) / tv:+.2f} %")
    return ", ".join(errs) or "-"


def main():
    warnings.simplefilter("ignore")
    if not DATA.is_dir():
        sys.exit(f"benchA not found at {DATA}")
    prof = bench_a_profile()
    labels = json.loads((DATA / "labels.json").read_text())
    print("benchA: profile from its 12 FRFs (profile build); held-out RMS of the twin's mean, "
          "µm x/y; 95 % interval coverage as predict ships it, % x/y\n")
    print("| log | truth | diagnosis | parameter error | held-out RMS before | after | "
          "coverage no learning | with learning | s |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for e in labels["logs"]:
        name = e["file"].split("/")[-1]
        cmd, pos = read(name)
        w0 = log_warmup(cmd[:, :2], prof.ts_s, prof)
        log = MotionLog(ts_s=prof.ts_s, cmd_mm=cmd, pos_mm=pos, source=name, kind="encoder",
                        warmup=w0)
        t0 = time.perf_counter()
        d = diagnose_log(log, prof)
        dt = time.perf_counter() - t0
        ho = d.holdout_rms_mm
        c0 = coverage(prof, cmd, pos, w0, False)
        c1 = coverage(prof, cmd, pos, w0, True)
        print(f"| {name[:-4]} | {describe(e['effects'])} | {describe(d.effects)} | "
              f"{param_error(e['effects'], d.effects)} | "
              f"{ho['before']['x'] * 1e3:.1f} / {ho['before']['y'] * 1e3:.1f} | "
              f"{ho['after']['x'] * 1e3:.1f} / {ho['after']['y'] * 1e3:.1f} | "
              f"{c0[0]:.1f} / {c0[1]:.1f} | {c1[0]:.1f} / {c1[1]:.1f} | {dt:.1f} |")

    # pooled over plants drawn from the profile's own spread (the population the chance
    # constraint is about), on benchA's butterfly command
    cmd, _ = read("log_01.csv")
    rng = np.random.default_rng(5)
    print("\nplants drawn from the benchA profile's spread, log_01's command, 1 µm noise, "
          "predict without learning (σ_ε estimated from each log):")
    for i, ax in enumerate("xy"):
        ins = []
        for h in draw_impulses(prof, ax, rng, 200):
            meas = respond(cmd[:, i], h) + 0.001 * rng.standard_normal(len(cmd))
            mean, std = axis_twin(prof, ax).run(cmd[:, i], meas, learn=False)
            ins.append(np.abs(meas - mean) <= Z95 * std)
        print(f"  {ax}: {100 * np.mean(ins):.1f} % inside the 95 % interval (200 plants)")


if __name__ == "__main__":
    main()
