"""The twin and the diagnosis on benchA, a machine simulated apart from this project
(issue 19's benchmark). Reads ../shared/data/independent/ (never copied).

For every benchA log: the truth (labels.json), the diagnosis, the parameter error, the held-out
RMS before / after (the twin's mean with the profile as is / with the profile ``diagnose -o``
writes), and the coverage of the 95 % interval as ``predict`` ships it, without and with
learning (after a log's warm-up). Then the coverage pooled over plants drawn from the profile's
spread, as the optimizer's chance constraint assumes it.

    python benchmarks/independent.py            # ~1–2 min on 2 cores
    python benchmarks/independent.py --data DIR # another data set in benchA's layout
    python benchmarks/independent.py --sensor-offset 0.05 -0.03   # encoders zeroed off

``--data`` takes any directory laid out as benchA is (``frf/x_*.csv``, ``frf/y_*.csv``,
``logs/*.csv`` with ``t,x_cmd,y_cmd,x,y``, ``labels.json``): a machine we have not seen is
judged the same way (benchmarks/foreign.py does so for machines of tests/foreign/machines.py).

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
from gcode_feedopt.closedloop.logs import (MotionLog, log_warmup, remove_sensor_offsets,
                                           twin_mean_xy)
from gcode_feedopt.profile import load_profile
from gcode_feedopt.profile.build import build_from_frfs
from gcode_feedopt.twin.model import axis_twin
from gcode_feedopt.twin.physics import draw_impulses, machine_command
from gcode_feedopt.vm.plant import respond

REPO = pathlib.Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data" / "independent"
Z95 = 1.959964
#: the parameter that sizes each kind (labels.json's names)
KEY = {"delay": "seconds", "backlash": "magnitude_mm", "friction": "magnitude_mm",
       "periodic_time": "amplitude_mm", "periodic_position": "wavelength_mm",
       "resonance_shift": "frequency_hz", "gain": "scale", "cross_coupling": "mm_per_mm_s2"}


def bench_a_profile(data=DATA, name="benchA"):
    frf = pathlib.Path(data) / "frf"
    prof, _ = build_from_frfs(load_profile("ender3pro"),
                              {a: sorted(frf.glob(f"{a}_*.csv")) for a in "xy"}, name=name)
    return prof


def read(name, data=DATA):
    a = np.loadtxt(pathlib.Path(data) / "logs" / name, delimiter=",", skiprows=1)
    cmd = np.column_stack([a[:, 1:3], np.zeros(len(a))])
    pos = np.column_stack([a[:, 3:5], np.zeros(len(a))])
    return cmd, pos


def encoder_log(name, data, prof, offset_mm=(0.0, 0.0), subtract=True) -> MotionLog:
    """Log ``name`` of a data set as ``diagnose`` reads an encoder log (``load_log``: its
    warm-up for ``prof``'s twin, a sensor offset subtracted unless ``subtract`` is false), its
    measured x, y first shifted by ``offset_mm`` (an encoder zeroed off the machine's)."""
    cmd, pos = read(name, data)
    pos[:, :2] += offset_mm
    log = MotionLog(ts_s=prof.ts_s, cmd_mm=cmd, pos_mm=pos, source=name, kind="encoder",
                    warmup=log_warmup(cmd[:, :2], prof.ts_s, prof))
    if not subtract:
        return log
    log, notes = remove_sensor_offsets(log, twin_mean_xy(prof, machine_command(prof, cmd)))
    if any("cannot tell" in n for n in notes):
        log.info["cannot_tell"] = True
    return log


def coverage(prof, cmd, pos, w0, learn):
    """% of samples (after the warm-up) inside the 95 % interval, per axis, as predict runs
    (on the machine's input: the commands through the profile's input shaper, if any)."""
    out = []
    cmd = machine_command(prof, cmd)
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


def evaluate(data=DATA, prof=None, offset_mm=(0.0, 0.0)):
    """One row per log of the data set: truth, diagnosis, parameter error, held-out RMS
    before / after (µm), prior RMS error of the twin's mean and of "actual = command" (µm),
    coverage without / with learning (%), seconds; the measured x, y shifted by
    ``offset_mm`` first (an encoder zeroed off the machine's), the offsets ``load_log``
    subtracted."""
    data = pathlib.Path(data)
    prof = prof or bench_a_profile(data)
    labels = json.loads((data / "labels.json").read_text())
    rows = []
    for e in labels["logs"]:
        name = e["file"].split("/")[-1]
        log = encoder_log(name, data, prof, offset_mm)
        cmd, pos, w0 = log.cmd_mm, log.pos_mm, log.warmup
        t0 = time.perf_counter()
        d = diagnose_log(log, prof)
        dt = time.perf_counter() - t0
        prior, none = [], []
        cmd_in = machine_command(prof, cmd)
        for i, ax in enumerate("xy"):
            mean, _ = axis_twin(prof, ax).run(cmd_in[:, i], pos[:, i], learn=False, warmup=w0)
            prior.append(1e3 * np.sqrt(np.mean((pos[w0:, i] - mean[w0:]) ** 2)))
            none.append(1e3 * np.sqrt(np.mean((pos[w0:, i] - cmd[w0:, i]) ** 2)))
        rows.append({"log": name[:-4], "truth": e["effects"], "diagnosis": d.effects,
                     "truth_s": describe(e["effects"]), "diagnosis_s": describe(d.effects),
                     "param_error": param_error(e["effects"], d.effects),
                     "before": d.holdout_rms_mm["before"], "after": d.holdout_rms_mm["after"],
                     "prior_um": prior, "command_um": none,
                     "cov0": coverage(prof, cmd, pos, w0, False),
                     "cov1": coverage(prof, cmd, pos, w0, True), "s": dt,
                     "offset_mm": log.info.get("sensor_offset_mm", {}),
                     "cannot_tell": log.info.get("cannot_tell", False)})
    return rows


def print_rows(rows):
    print("| log | truth | diagnosis | parameter error | held-out RMS before | after | "
          "prior twin / command-only RMS | coverage no learning | with learning | s |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        ho0, ho1, p, c = r["before"], r["after"], r["prior_um"], r["command_um"]
        print(f"| {r['log']} | {r['truth_s']} | {r['diagnosis_s']} | {r['param_error']} | "
              f"{ho0['x'] * 1e3:.1f} / {ho0['y'] * 1e3:.1f} | "
              f"{ho1['x'] * 1e3:.1f} / {ho1['y'] * 1e3:.1f} | "
              f"{p[0]:.1f} / {c[0]:.1f}, {p[1]:.1f} / {c[1]:.1f} | "
              f"{r['cov0'][0]:.1f} / {r['cov0'][1]:.1f} | {r['cov1'][0]:.1f} / {r['cov1'][1]:.1f} | "
              f"{r['s']:.1f} |")


def main():
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=pathlib.Path, default=DATA,
                    help="a data set in benchA's layout (default ../shared/data/independent)")
    ap.add_argument("--sensor-offset", type=float, nargs=2, metavar=("DX", "DY"),
                    default=(0.0, 0.0), help="shift every log's measured x, y by DX, DY mm (an "
                    "encoder zeroed off the machine's) and report what load_log subtracts")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    if not args.data.is_dir():
        sys.exit(f"data set not found at {args.data}")
    prof = bench_a_profile(args.data, args.data.name)
    print(f"{args.data.name}: profile from its FRFs (profile build); held-out RMS of the twin's "
          "mean, µm x/y; prior RMS error of the twin's mean vs of actual = command, µm x, y; "
          "95 % interval coverage as predict ships it, % x/y\n")
    rows = evaluate(args.data, prof, tuple(args.sensor_offset))
    print_rows(rows)
    if any(args.sensor_offset):
        def kinds(effects):
            return sorted((e["kind"], e["axis"]) for e in effects if e["kind"] != "none")

        right = sum(kinds(r["truth"]) == kinds(r["diagnosis"]) for r in rows)
        kept = sum(kinds(r["truth"]) == kinds(diagnose_log(
            encoder_log(r["log"] + ".csv", args.data, prof, tuple(args.sensor_offset),
                        subtract=False), prof).effects) for r in rows)
        print(f"\nmeasured x, y shifted by {args.sensor_offset[0]:+g} / "
              f"{args.sensor_offset[1]:+g} mm: diagnosis right (kinds and axes) on {right} of "
              f"{len(rows)} ({kept} with the offsets left in)")
        for r in rows:
            got = ", ".join(f"{a} (error {1e3 * (o - args.sensor_offset['xy'.index(a)]):+.2f} "
                            f"µm)" for a, o in r["offset_mm"].items()) or "nothing"
            print(f"  {r['log']}: subtracted {got}"
                  + ("; a constant it cannot tell from a gain" if r["cannot_tell"] else ""))
    if args.data != DATA or any(args.sensor_offset):
        return

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
