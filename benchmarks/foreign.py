"""The twin and the diagnosis on machines of structures we did not simulate (issue 19).

Draws machines from tests/foreign/machines.py (belt + frame, belt + hotend on a flexible mount,
a PID servo on a lead screw, a corexy with mismatched belts; transport delays; random FRF grids,
noise and sensor quantisation), writes each as a data set in benchA's layout and judges it as
benchmarks/independent.py judges benchA: profile built from its FRFs, every log diagnosed,
prior prediction vs "actual = command", coverage of the 95 % interval without / with learning.

    python benchmarks/foreign.py                 # seeds 0–7, ~1 min each on 2 cores
    python benchmarks/foreign.py --seeds 3 5 --kind servo_screw --keep /tmp/foreign
    python benchmarks/foreign.py --seeds 60 61 --shaper mzv [--causal] [--unstated]
    python benchmarks/foreign.py --seeds 0 1 2 3 4 5 --measurements 1   # one FRF per axis

``--shaper``: the machines print through an input shaper at their dominant modes (Klipper's
centred pulses; ``--causal``: Marlin's), measured without it (the FRFs); the profile states it
in ``firmware.input_shaper`` as its owner would, unless ``--unstated``.
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import sys
import tempfile
import warnings

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "benchmarks")]

from independent import bench_a_profile, evaluate, print_rows  # noqa: E402
from tests.foreign.machines import KINDS, make_machine, with_shaper, write_dataset  # noqa: E402


def stated(prof, mach):
    """``prof`` with the foreign machine's input shapers stated in firmware.input_shaper."""
    from gcode_feedopt.firmware.shaper import Shaper
    sh = {a: Shaper.from_dict(c) for a, c in mach.shapers.items()}
    return dataclasses.replace(prof, firmware=dataclasses.replace(prof.firmware, input_shaper=sh))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=list(range(8)))
    ap.add_argument("--kind", choices=KINDS, default=None)
    ap.add_argument("--keep", type=pathlib.Path, default=None,
                    help="write the data sets here (default: a temporary folder)")
    ap.add_argument("--no-effects", action="store_true", help="clean logs only")
    ap.add_argument("--shaper", choices=("zv", "zvd", "mzv"), default=None,
                    help="print through this input shaper at the dominant modes")
    ap.add_argument("--causal", action="store_true", help="the shaper's pulses causal (Marlin)")
    ap.add_argument("--unstated", action="store_true",
                    help="the profile does not state the shaper")
    ap.add_argument("--measurements", type=int, default=None,
                    help="FRFs per axis (default: the machine's own draw, 3–8)")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    base = args.keep or pathlib.Path(tempfile.mkdtemp(prefix="foreign-"))
    summary = []
    for seed in args.seeds:
        mach = make_machine(seed, args.kind)
        if args.measurements:
            mach = dataclasses.replace(mach, n_meas=args.measurements)
        if args.shaper:
            mach = with_shaper(mach, args.shaper, centred=not args.causal)
        out = base / f"foreign-{seed}"
        labels = write_dataset(mach, out, effects=not args.no_effects)
        print(f"\n## {mach.describe()}\n")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            prof = bench_a_profile(out, out.name)
        if mach.shapers and not args.unstated:
            prof = stated(prof, mach)
        for w in caught:
            print(f"  warning: {w.message}")
        rows = evaluate(out, prof)
        print_rows(rows)
        summary.append((mach, rows, {(e["kind"], e["axis"]) for e in labels["inherent"]}))
    print("\n## summary: clean logs named none (or only an inherent effect: a corexy's "
          "cross-talk); effects named (kind, axis); effect logs with a (kind, axis) named "
          "beside the truth; worst prior / command-only RMS ratio; coverage no learning / "
          "learning, min over logs and axes\n")
    print("| seed | kind | clean → none | effects named | with another named | "
          "prior/command worst | cov0 min | cov1 min |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for mach, rows, inherent in summary:
        clean = [r for r in rows if r["truth_s"] == "none"]
        eff = [r for r in rows if r["truth_s"] != "none"]
        ok_clean = sum(all((g["kind"], g["axis"]) in inherent for g in r["diagnosis"]
                           if g["kind"] != "none") for r in clean)
        named = sum(all(any(g["kind"] == t["kind"] and g["axis"] == t["axis"] for g in r["diagnosis"])
                        for t in r["truth"]) for r in eff)
        # a (kind, axis) named beside the truth's and a corexy's own cross-talk
        extra = sum(any(g["kind"] != "none" and (g["kind"], g["axis"]) not in inherent
                        and not any(g["kind"] == t["kind"] and g["axis"] == t["axis"]
                                    for t in r["truth"])
                        for g in r["diagnosis"]) for r in eff)
        ratio = max(p / max(c, 1e-9) for r in clean for p, c in zip(r["prior_um"], r["command_um"]))
        c0 = min(min(r["cov0"]) for r in clean)
        c1 = min(min(r["cov1"]) for r in rows)
        print(f"| {mach.seed} | {mach.kind} | {ok_clean}/{len(clean)} | {named}/{len(eff)} | "
              f"{extra}/{len(eff)} | {ratio:.2f} | {c0:.1f} | {c1:.1f} |")


if __name__ == "__main__":
    main()
