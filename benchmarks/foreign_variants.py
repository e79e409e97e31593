"""Effects in forms neither benchA nor tests/foreign's other logs write (issue 19: machines
nobody here has seen).

benchA's fan runs from t = 0 and each of its logs carries one effect of a kind. On a printer
the part-cooling fan is switched on after the first layers, and a belt drive has its tooth
pitch and its pulley's runout at once. For each seed this writes the machine's FRFs and clean
logs and then ``write_dataset(..., variants=True)``'s logs (tests/foreign/machines.py,
``_variant_effects``): a fan switched on 40 % into a rose (not on a corexy), two
eccentricities on one axis (λ 1.5–3 mm and 20–45 mm) on a Benchy layer and, on the belt
machines, a friction of the carriage's own velocity (benchA's form) on a rose; builds the
profile from the FRFs as a user would and diagnoses each log. Per effect: the truth, what was
named for it (the named effect of its kind and axis nearest in frequency / wavenumber / lag;
a stated tie is shown), the parameter errors, and anything named beside the truth (a corexy's
own cross-talk excepted).

A log is **correct** when each true effect is named on its axis with its frequency within
0.1 Hz / its wavelength or lag within 5 %, its amplitude within 10 %, and nothing else is
named.

    python benchmarks/foreign_variants.py                 # seeds 700–711, ~20 s each
    python benchmarks/foreign_variants.py --seeds 703 --keep /tmp/fvar
"""

from __future__ import annotations

import pathlib
import sys
import time

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(REPO), str(REPO / "benchmarks")]

from foreign_effects import run_seeds, write_seed  # noqa: E402
from gcode_feedopt.closedloop.diagnose import diagnose_log  # noqa: E402
from independent import encoder_log  # noqa: E402

#: the variant logs' kinds, and what a named effect is matched to its truth by
KEY = {"periodic_time": "frequency_hz", "periodic_position": "wavelength_mm",
       "friction": "magnitude_mm"}
TOL = {"frequency_hz": 0.1, "wavelength_mm": 0.05, "amplitude_mm": 0.10, "magnitude_mm": 0.05}


def _distance(kind, truth, got):
    a, b = truth["params"][KEY[kind]], got["params"][KEY[kind]]
    return abs(1 / a - 1 / b) if kind == "periodic_position" else abs(a - b)


def judge(truths: list, got: list, inherent: set) -> dict:
    """The true effects and the named ones of their kind and axis paired nearest first (in
    frequency / wavenumber); the rest named beside the truth."""
    left = [g for g in got if g["kind"] != "none" and (g["kind"], g["axis"]) not in inherent]
    pairs = sorted(((_distance(t["kind"], t, g), i, j) for i, t in enumerate(truths)
                    for j, g in enumerate(left)
                    if g["kind"] == t["kind"] and g["axis"] == t["axis"]))
    match = {}
    for _, i, j in pairs:
        if i not in match and j not in match.values():
            match[i] = j
    rows, ok = [], True
    for i, t in enumerate(truths):
        if i not in match:
            rows.append((t, None, None, None))
            ok = False
            continue
        g = left[match[i]]
        k = KEY[t["kind"]]
        tv, gv = t["params"][k], g["params"][k]
        err = gv - tv if k == "frequency_hz" else (gv - tv) / tv
        ta = t["params"].get("amplitude_mm")
        amp = None if ta is None else (g["params"]["amplitude_mm"] - ta) / ta
        ok &= (abs(err) <= TOL[k]) and (amp is None or abs(amp) <= TOL["amplitude_mm"])
        rows.append((t, g, err, amp))
    others = [g for j, g in enumerate(left) if j not in match.values()]
    return {"effects": rows, "others": others, "correct": ok and not others}


def run_seed(seed: int, base: pathlib.Path) -> list:
    mach, out, labels, prof, inherent = write_seed(seed, base, variants=True)
    rows = []
    for e in labels["logs"]:
        if e["effects"][0]["kind"] not in KEY:
            continue
        name = e["file"].split("/")[-1]
        t0 = time.perf_counter()
        d = diagnose_log(encoder_log(name, out, prof), prof)
        rows.append({"seed": seed, "machine": mach.kind, "log": name[:-4], "s":
                     time.perf_counter() - t0, "before": d.holdout_rms_mm["before"],
                     "after": d.holdout_rms_mm["after_fitted"],
                     **judge(e["effects"], d.effects, inherent)})
    return rows


def _effect_s(e) -> str:
    p = e["params"]
    s = f"{e['kind']} {e['axis']} {KEY[e['kind']]}={p[KEY[e['kind']]]:.5g}"
    if "amplitude_mm" in p:
        s += f" A={p['amplitude_mm']:.4g}"
    if "form" in p:
        s += f" [{p['form']}]"
    if "tie" in p:
        s += f" (tie: {_other_s({**p['tie'], 'axis': e['axis']})})"
    on = p.get("switched_on_s", e.get("physics", {}).get("onset_s"))
    return s + (f" on at {on:.3f} s" if on is not None else "")


def _other_s(e) -> str:
    num = {k: v for k, v in e["params"].items() if isinstance(v, float) and k != "phase_rad"}
    s = f"{e['kind']} {e['axis']} " + " ".join(f"{k}={v:.4g}" for k, v in num.items())
    if "tie" in e["params"]:
        s += f" (tie: {_other_s({**e['params']['tie'], 'axis': e['axis']})})"
    return s


def print_rows(rows):
    print("| seed | machine | log | truth | named for it | error | amplitude error | "
          "named beside | correct | held-out RMS before x/y µm | after (fitted) x/y µm |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for r in rows:
        for i, (t, g, err, amp) in enumerate(r["effects"]):
            if g is None:
                named, es, amps = "missed", "-", "-"
            else:
                named = _effect_s(g)
                es = (f"{err:+.3f} Hz" if t["kind"] == "periodic_time" else f"{100 * err:+.1f} %")
                amps = "-" if amp is None else f"{100 * amp:+.1f} %"
            last = i == len(r["effects"]) - 1
            b, a = r["before"], r["after"]
            print(f"| {r['seed']} | {r['machine']} | {r['log']} | {_effect_s(t)} | {named} | "
                  f"{es} | {amps} | "
                  + ("; ".join(_other_s(o) for o in r["others"]) or "-" if last else "")
                  + f" | {('yes' if r['correct'] else 'no') if last else ''} | "
                  + (f"{1e3 * b['x']:.1f} / {1e3 * b['y']:.1f} | "
                     f"{1e3 * a['x']:.1f} / {1e3 * a['y']:.1f} |" if last else " | |"),
                  flush=True)


def summary(rows):
    print("\n| log kind | correct | effects named (kind, axis) | named beside the truth |")
    print("| --- | --- | --- | --- |")
    for kind, what in (("periodic_time", "fan switched on"),
                       ("periodic_position", "two eccentricities"),
                       ("friction", "friction of the carriage's velocity")):
        rs = [r for r in rows if r["effects"][0][0]["kind"] == kind]
        if not rs:
            continue
        n_eff = sum(len(r["effects"]) for r in rs)
        named = sum(g is not None for r in rs for _, g, _, _ in r["effects"])
        print(f"| {what} | {sum(r['correct'] for r in rs)}/{len(rs)} | {named}/{n_eff} | "
              f"{sum(bool(r['others']) for r in rs)}/{len(rs)} |")


if __name__ == "__main__":
    run_seeds(__doc__, list(range(700, 712)), "foreign-variants-", run_seed, print_rows, summary)
