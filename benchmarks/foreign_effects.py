"""Does the diagnosis name the drive's effects on foreign physics? (issue 19)

benchmarks/foreign.py judges the effects tests/foreign/machines.py has always drawn (delay,
gain, a fan, a resonance shift). This one writes each seed's machine with the catalogue's other
kinds applied in that module's physics (``write_dataset(..., more_effects=True)``: a dead band
in the drive, a pulley / screw eccentricity, a Coulomb friction on the carriage / table, and —
not on a corexy — the other axis's acceleration pushing the frame: two logs, its actual
acceleration (the reaction of its real motion, as benchA) and its commanded one), builds the
profile from the machine's FRFs as a user would, diagnoses each of those logs and compares with
the truth. Per log: the effect's own size (RMS of what it moves its axis by, noise-free), the
held-out RMS before / after, and round 0's candidate of the true kind with the tests it failed.

A log is **correct** when the diagnosis names the true kind on the true axis with its
parameter (backlash / friction ``magnitude_mm``, periodic_position ``wavelength_mm``,
cross_coupling ``mm_per_mm_s2``) within 5 %. A corexy's own cross-talk (``inherent``) is not
held against it. On a servo the friction's and the cross-coupling's labels are a scale, not a
steady lag (its integrator takes a steady force out): marked ``*``.

    python benchmarks/foreign_effects.py                  # seeds 0–11, ~10–20 s each
    python benchmarks/foreign_effects.py --seeds 11 14 --keep /tmp/feff
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import tempfile
import time
import warnings

import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "benchmarks")]

from gcode_feedopt.closedloop.diagnose import diagnose_log  # noqa: E402
from independent import bench_a_profile, describe, encoder_log, read  # noqa: E402
from tests.foreign.machines import (Machine, _more_effects, apply_factors,  # noqa: E402
                                    make_machine, respond_xy, write_dataset)

NEW = ("backlash", "periodic_position", "friction", "cross_coupling")
KEY = {"backlash": "magnitude_mm", "friction": "magnitude_mm",
       "periodic_position": "wavelength_mm", "cross_coupling": "mm_per_mm_s2"}
TOL = 0.05


def judge(truth: dict, got: list, inherent: set) -> dict:
    """The diagnosis of one log against its one true effect."""
    g = next((g for g in got if g["kind"] == truth["kind"] and g["axis"] == truth["axis"]), None)
    others = [e for e in got if e["kind"] != "none" and e is not g
              and (e["kind"], e["axis"]) not in inherent]
    err = amp_err = None
    if g is not None:
        k = KEY[truth["kind"]]
        if k in g["params"]:
            tv, gv = truth["params"][k], g["params"][k]
            err = (gv - tv) / tv
        if truth["kind"] == "periodic_position":
            ta = truth["params"]["amplitude_mm"]
            amp_err = (g["params"]["amplitude_mm"] - ta) / ta
    return {"named": g is not None, "err": err, "amp_err": amp_err, "others": others,
            "form": None if g is None else g["params"].get("form"),
            "correct": err is not None and abs(err) <= TOL}


def effect_rms_um(mach, labels, out) -> dict:
    """(kind, axis) -> RMS (µm) of what the effect moves its axis by in the physics, noise-free
    (the log's plant with the effect minus without): how large the thing to be named is."""
    plant = apply_factors(mach, labels["plant"]["factors"])
    quiet = Machine(**{**mach.__dict__, "sensor_q_mm": 1e-9, "sensor_noise_mm": 0.0})
    res = {}
    more = _more_effects(mach, plant, np.random.default_rng(20_000 + mach.seed))
    # the drive's effect logs are the data set's last ones, in this order
    for (path, kw, lab), e in zip(more, labels["logs"][-len(more):]):
        assert e["effects"][0]["kind"] == lab[0]["kind"]
        cmd, _ = read(e["file"].split("/")[-1], out)
        i = "xy".index(lab[0]["axis"])
        with_ = respond_xy(quiet, plant, cmd[:, 0], cmd[:, 1], 0.002, **kw)[i]
        without = respond_xy(quiet, plant, cmd[:, 0], cmd[:, 1], 0.002)[i]
        res[e["file"]] = 1e3 * float(np.sqrt(np.mean((with_ - without) ** 2)))
    return res


def why_not(truth, cands) -> str:
    """Round 0's candidate of the true kind and axis, and the tests it failed."""
    c = next((c for c in cands if c.kind == truth["kind"] and c.axis == truth["axis"]), None)
    if c is None:
        return "no candidate"
    k = KEY[truth["kind"]]
    v = c.params.get(k)
    fails = []
    if c.t_fit <= c.crit_fit:
        fails.append(f"fit T {c.t_fit:.0f} ≤ {c.crit_fit:.0f}")
    if c.t_hold <= c.crit_hold:
        fails.append(f"held-out T {c.t_hold:.1f} ≤ {c.crit_hold:.1f}")
    if c.fraction < 0.2:
        fails.append(f"explains {100 * c.fraction:.0f} % < 20 %")
    rank = [x.kind + " " + x.axis for x in cands].index(c.kind + " " + c.axis) + 1
    vs = "n/a" if v is None else f"{v:.4g}"
    return (f"cand. #{rank} {k}={vs} [{c.form}]: " + (", ".join(fails) or "passes"))


def write_seed(seed: int, base: pathlib.Path, **logs) -> tuple:
    """(machine, folder, labels, profile, inherent (kind, axis)) of a seed's machine written
    under ``base`` with its clean logs and ``write_dataset``'s ``logs`` keywords, the profile
    built from its FRFs as a user would."""
    mach = make_machine(seed)
    out = base / f"foreign-{seed}"
    labels = write_dataset(mach, out, effects=False, **logs)
    prof = bench_a_profile(out, out.name)
    inherent = {(e["kind"], e["axis"]) for e in labels["inherent"]}
    return mach, out, labels, prof, inherent


def run_seed(seed: int, base: pathlib.Path) -> list:
    mach, out, labels, prof, inherent = write_seed(seed, base, more_effects=True)
    size = effect_rms_um(mach, labels, out)
    rows = []
    for e in labels["logs"]:
        truth = e["effects"][0]
        if truth["kind"] not in NEW:
            continue
        name = e["file"].split("/")[-1]
        log = encoder_log(name, out, prof)
        t0 = time.perf_counter()
        d = diagnose_log(log, prof)
        rows.append({"seed": seed, "machine": mach.kind, "log": name[:-4], "truth": truth,
                     "diagnosis": d.effects, "before": d.holdout_rms_mm["before"],
                     "after": d.holdout_rms_mm["after"], "s": time.perf_counter() - t0,
                     "size_um": size[e["file"]],
                     "why": why_not(truth, d.candidates),
                     **judge(truth, d.effects, inherent)})
    return rows


def _truth_s(t):
    k = KEY[t["kind"]]
    s = f"{t['kind']} {t['axis']} {k}={t['params'][k]:.5g}"
    if t["kind"] == "periodic_position":
        s += f" A={t['params']['amplitude_mm']:.4g}"
    if t["kind"] == "cross_coupling":
        s += f" ({t['physics']['source']} acc.)"
    if t.get("physics", {}).get("steady") is False:
        s += " *"
    return s


def _diag_s(effects):
    parts = []
    for e in effects:
        if e["kind"] == "none":
            continue
        if e["kind"] == "cross_coupling" and "mm_per_mm_s2" not in e["params"]:
            s = f"cross_coupling {e['axis']} coefficient={e['params']['coefficient']:.3g}"
        else:
            s = describe([e])
        if e["kind"] == "periodic_position":
            s += f" A={e['params']['amplitude_mm']:.4g}"
        form = e["params"].get("form")
        parts.append(s + (f" [{form}]" if form else ""))
    return "; ".join(parts) or "none"


def print_rows(rows):
    print("| seed | machine | log | truth | effect RMS µm | diagnosis | parameter error | "
          "correct | held-out RMS before x/y µm | after x/y µm | true kind's round-0 candidate |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        err = ("missed" if not r["named"] else "n/a" if r["err"] is None
               else f"{100 * r['err']:+.1f} %")
        if r["amp_err"] is not None:
            err += f" (A {100 * r['amp_err']:+.1f} %)"
        b, a = r["before"], r["after"]
        print(f"| {r['seed']} | {r['machine']} | {r['log']} | {_truth_s(r['truth'])} | "
              f"{r['size_um']:.1f} | {_diag_s(r['diagnosis'])} | {err} | "
              f"{'yes' if r['correct'] else 'no'} | "
              f"{1e3 * b['x']:.1f} / {1e3 * b['y']:.1f} | "
              f"{1e3 * a['x']:.1f} / {1e3 * a['y']:.1f} | {r['why']} |", flush=True)


def summary(rows):
    print("\n| kind | correct | named (kind, axis) | median abs parameter error (named) | "
          "other effects named too |")
    print("| --- | --- | --- | --- | --- |")
    def group(r):
        t = r["truth"]
        return t["kind"] + (f" ({t['physics']['source']} acc.)" if t["kind"] == "cross_coupling"
                            else "")

    for k in ("backlash", "periodic_position", "friction", "cross_coupling (actual acc.)",
              "cross_coupling (command acc.)"):
        rs = [r for r in rows if group(r) == k]
        if not rs:
            continue
        errs = [abs(r["err"]) for r in rs if r["err"] is not None]
        med = f"{100 * np.median(errs):.1f} %" if errs else "-"
        print(f"| {k} | {sum(r['correct'] for r in rs)}/{len(rs)} | "
              f"{sum(r['named'] for r in rs)}/{len(rs)} | {med} | "
              f"{sum(bool(r['others']) for r in rs)}/{len(rs)} |")
    machines = sorted({r["machine"] for r in rows})
    print("\ncorrect / total by machine kind\n")
    print("| kind | " + " | ".join(machines) + " |")
    print("| --- |" + " --- |" * len(machines))
    for k in sorted({group(r) for r in rows}):
        cells = []
        for mk in machines:
            rs = [r for r in rows if group(r) == k and r["machine"] == mk]
            cells.append(f"{sum(r['correct'] for r in rs)}/{len(rs)}" if rs else "-")
        print(f"| {k} | " + " | ".join(cells) + " |")


def run_seeds(doc: str, seeds: list, prefix: str, run_seed, print_rows, summary):
    """A foreign-machine benchmark's command line (``--seeds``, ``--keep``): each seed's rows
    (``run_seed(seed, folder)``) printed as they come, then all of them and the summary."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=seeds)
    ap.add_argument("--keep", type=pathlib.Path, default=None,
                    help="write the data sets here (default: a temporary folder)")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    base = args.keep or pathlib.Path(tempfile.mkdtemp(prefix=prefix))
    rows = []
    for seed in args.seeds:
        print(f"\n## {make_machine(seed).describe()}\n", flush=True)
        new = run_seed(seed, base)
        print_rows(new)
        rows += new
    print("\n## all seeds\n")
    print_rows(rows)
    summary(rows)


if __name__ == "__main__":
    run_seeds(__doc__, list(range(12)), "foreign-effects-", run_seed, print_rows, summary)
