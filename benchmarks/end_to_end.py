"""End to end where the tolerance binds (issue 19, point 7): kinematic / conservative / pidd /
oracle planned, executed on a plant and judged on the plant.

A scenario is a machine, a path, the kinematic limits V and A, E_max and the stringencies η.
The machine is a profile (``ender3pro``, or ``benchA``: built from the 12 FRFs of
../shared/data/independent/frf as ``profile build`` builds it) with its X/Y acceleration limits
(profile and firmware M201) raised to the scenario's A, and the plant is one seeded draw of that
profile's own uncertainty (vm.plant.Plant): a machine of the population the twin describes, not
its mean.

Per η it prints, for every method, the whole-run cycle time, the time on the extruded contour,
RMS γ against the paper's limit (1 − η)·E_max, the fraction of extruded samples within E_max
and the plan's compute time:

- ``kinematic``: the firmware's plan at V, A;
- ``conservative``: the largest uniform scale of V and A whose run *on this plant* keeps
  RMS γ ≤ (1 − η)·E_max (optimize.methods.largest_passing_scale: the paper's rule; it is tuned on
  the plant, so it knows more than any planner that ships);
- ``pidd``: what `gcode-feedopt optimize` does (the offline slow-down optimizer with the
  profile's twin; it never sees the plant);
- ``pidd+learned``: the same after one print with pidd on this machine, its encoder log
  ``learn``ed (the weights, which machine of the profile's population this is, and the level of
  what the twin cannot predict, in place of the profile's σ_ε = 10 µm);
- ``oracle``: the same optimizer knowing the plant exactly (the physical limit).

and the targets: pidd ≤ 0.75 × conservative's cycle where the tolerance binds (conservative
scales the limits down), RMS γ within (1 − η)·E_max, within ≥ η; where the tolerance does not
bind (the kinematic plan keeps every sample within E_max on the plant), pidd = kinematic.

    python benchmarks/end_to_end.py [--scenario butterfly-ender3pro,...] [--eta 0.9,0.95,0.99]
                                    [--seed 1] [--methods kinematic,conservative,pidd,oracle]
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import pathlib
import sys
import tempfile
import time

import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]
INDEPENDENT = REPO.parent / "shared" / "data" / "independent"
BUTTERFLY = REPO / "sample_gcode" / "butterfly.gcode"

#: name: (machine, path, V mm/s, A mm/s², E_max mm)
SCENARIOS = {
    "butterfly-ender3pro": ("ender3pro", "butterfly", 150.0, 5000.0, 0.05),
    "butterfly-benchA": ("benchA", "butterfly", 150.0, 5000.0, 0.05),
    "rose-ender3pro": ("ender3pro", "rose", 250.0, 8000.0, 0.1),
    "rose-benchA": ("benchA", "rose", 250.0, 8000.0, 0.1),
    # the tolerance does not bind: the profile's own limits, E_max 0.2 mm
    "butterfly-ender3pro-loose": ("ender3pro", "butterfly", 70.0, 3000.0, 0.2),
}
METHODS = ("kinematic", "conservative", "pidd", "pidd+learned", "oracle")
#: a method name with ``:window`` plans with the receding-window LP (optimize.mpc, the paper's
#: full method) instead of the slow-down optimizer
OPTIMIZED = ("pidd", "oracle")


def machine(name: str):
    """The profile of a machine name (``benchA``: built from benchA's FRFs)."""
    from gcode_feedopt.profile import load_profile

    if name == "benchA":
        from gcode_feedopt.profile.build import build_from_frfs

        frf = INDEPENDENT / "frf"
        prof, _ = build_from_frfs(load_profile("ender3pro"),
                                  {a: sorted(frf.glob(f"{a}_*.csv")) for a in "xy"}, name="benchA")
        return prof
    return load_profile(name)


def with_limits(prof, vmax_mm_s: float, amax_mm_s2: float):
    """The profile with V and the X/Y acceleration limits (profile and firmware) set."""
    lim, fw = prof.limits, prof.firmware
    ax_a = dict(lim.axis_amax_mm_s2, x=amax_mm_s2, y=amax_mm_s2)
    fw_a = dict(fw.max_accel_mm_s2, x=amax_mm_s2, y=amax_mm_s2)
    ax_v = {k: max(v, vmax_mm_s) if k in "xy" else v for k, v in lim.axis_vmax_mm_s.items()}
    fw_v = {k: max(v, vmax_mm_s) if k in "xy" else v for k, v in fw.max_feed_mm_s.items()}
    return dataclasses.replace(
        prof, limits=dataclasses.replace(lim, vmax_mm_s=vmax_mm_s, amax_mm_s2=amax_mm_s2,
                                         axis_amax_mm_s2=ax_a, axis_vmax_mm_s=ax_v),
        firmware=dataclasses.replace(fw, accel_mm_s2=amax_mm_s2, travel_accel_mm_s2=amax_mm_s2,
                                     max_accel_mm_s2=fw_a, max_feed_mm_s=fw_v))


def rose_gcode(path: pathlib.Path, *, radius_mm: float = 40.0, petals: int = 5,
               n: int = 2000) -> pathlib.Path:
    """benchA's ``rose5`` path, r = R cos(k t), t ∈ [0, π], centred at (110, 110), as one
    extruded polyline of ``n`` chords (chord error < 1 µm at n = 2000)."""
    t = np.linspace(0.0, math.pi, n + 1)
    r = radius_mm * np.cos(petals * t)
    x, y = 110.0 + r * np.cos(t), 110.0 + r * np.sin(t)
    seg = np.hypot(np.diff(x), np.diff(y))
    e = np.concatenate([[0.0], np.cumsum(seg) * 0.033])
    lines = ["; rose r = 40 cos 5t (benchA's rose5), one layer", "G21", "G90", "M82", "G92 E0",
             f"G0 X{x[0]:.4f} Y{y[0]:.4f} Z0.200 F6000", "G1 F1800"]
    lines += [f"G1 X{x[i]:.4f} Y{y[i]:.4f} E{e[i]:.5f}" for i in range(1, n + 1)]
    path.write_text("\n".join(lines) + "\n")
    return path


def scenario_path(kind: str, prof, tmp: pathlib.Path):
    from gcode_feedopt.pipeline import path_for, read_for

    src = BUTTERFLY if kind == "butterfly" else rose_gcode(tmp / "rose.gcode")
    return path_for(read_for(src, prof), prof)


@dataclasses.dataclass
class Row:
    method: str
    cycle_s: float
    contour_s: float
    rms_gamma_um: float
    within: float
    compute_s: float
    info: dict


def learned_once(path, prof, plant, tol, eta, tmp: pathlib.Path):
    """The profile after one print: pidd's plan run on ``plant``, its encoder log (1 µm of
    noise) read back and ``learn``ed (closedloop.learn: the weights, which machine of the
    population this is, and the level of what the twin cannot predict)."""
    import warnings

    from gcode_feedopt.closedloop.learn import learn_logs
    from gcode_feedopt.closedloop.logs import load_log
    from gcode_feedopt.optimize.methods import plan_schedule, vm_trajectory
    from gcode_feedopt.vm import effects as fx
    from gcode_feedopt.vm.log import write_log

    sch = plan_schedule("pidd", path, prof, tolerance_mm=tol, stringency=eta)
    tr = vm_trajectory(path, sch.s_mm, sch.ts_s)
    noisy = type(plant).from_impulse(plant.ts_s, plant.impulse, [
        *plant.effects, fx.SensorNoise("x", std_mm=0.001), fx.SensorNoise("y", std_mm=0.001)],
        seed=plant.seed + 1)
    log = tmp / "first_print.csv"
    write_log(log, tr.t_s, tr.pos_mm, noisy.simulate(tr).measured_mm, tr.e_mm)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return learn_logs(prof, [load_log(log, prof)])[0]


def run(method, path, prof, plant, tol, eta, **opts) -> Row:
    """Plan ``method``, execute the plan on ``plant``, judge it there. ``pidd+learned``: pidd
    with the profile ``learn``ed from one earlier print on the same plant (``opts['tmp']``)."""
    from gcode_feedopt.optimize.methods import plan_schedule, vm_trajectory
    from gcode_feedopt.vm.metrics import evaluate

    tmp = opts.pop("tmp", None)
    if method.startswith("pidd+learned"):
        prof = learned_once(path, prof, plant, tol, eta, tmp or pathlib.Path(tempfile.mkdtemp()))
        method = "pidd" + method[len("pidd+learned"):]
    name, _, optimizer = method.partition(":")
    if optimizer:
        opts["optimizer"] = optimizer
    t0 = time.perf_counter()
    sch = plan_schedule(name, path, prof, tolerance_mm=tol, stringency=eta, plant=plant, **opts)
    dt = time.perf_counter() - t0
    tr = vm_trajectory(path, sch.s_mm, sch.ts_s)
    m = evaluate(tr, plant.run(tr), tol)
    return Row(method, m.cycle_time_s, m.n_evaluated * tr.ts_s, 1000 * m.rms_gamma_mm,
               m.within_fraction, dt, dict(sch.info))


def verdict(rows: dict, tol: float, eta: float) -> str:
    """The point-7 targets of this η, one line."""
    lim = 1000 * (1 - eta) * tol
    k, c = rows.get("kinematic"), rows.get("conservative")
    return " | ".join(_verdict(m, p, k, c, lim, eta) for m, p in rows.items()
                      if m.startswith("pidd"))


def _verdict(name, p, k, c, lim, eta):
    ok_g = p.rms_gamma_um <= lim + 1e-9
    ok_w = p.within >= eta
    parts = [f"{name}: RMS γ {p.rms_gamma_um:.2f} ≤ {lim:.2f} µm: {'met' if ok_g else 'NOT met'}",
             f"within {p.within:.4f} ≥ {eta:g}: {'met' if ok_w else 'NOT met'}"]
    if k is not None and k.within >= 1.0:
        same = abs(p.cycle_s - k.cycle_s) <= 0.5 * 0.002
        parts.append(f"not binding (kinematic all within): = kinematic "
                     f"{'met' if same else 'NOT met'} ({p.cycle_s:.3f} vs {k.cycle_s:.3f} s)")
    elif c is not None and c.info.get("conservative_scale", 1.0) < 1.0:
        ratio = p.cycle_s / c.cycle_s
        parts.append(f"/conservative {ratio:.3f} ≤ 0.75: {'met' if ratio <= 0.75 else 'NOT met'}")
    elif c is not None:
        parts.append("binds on a few samples only (conservative x1)")
    return "; ".join(parts)


def main(argv=None):
    from gcode_feedopt.vm.plant import Plant

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default="butterfly-ender3pro,butterfly-benchA")
    ap.add_argument("--eta", default="0.9,0.95,0.99")
    ap.add_argument("--seed", type=int, default=1, help="plant draw")
    ap.add_argument("--methods", default=",".join(METHODS))
    a = ap.parse_args(argv)
    tmp = pathlib.Path(tempfile.mkdtemp())
    methods = [m for m in a.methods.split(",") if m]
    for name in a.scenario.split(","):
        mach, kind, V, A, tol = SCENARIOS[name]
        prof = with_limits(machine(mach), V, A)
        path = scenario_path(kind, prof, tmp)
        plant = Plant(prof, seed=a.seed)
        print(f"\n== {name}: {mach} draw seed {a.seed}, {kind}, V {V:g} mm/s, A {A:g} mm/s², "
              f"E_max {tol:g} mm")
        print(f"{'η':>5} {'method':>13} {'cycle s':>8} {'contour s':>9} {'RMS γ µm':>9} "
              f"{'limit':>6} {'within':>7} {'compute s':>9}  note")
        for eta in (float(e) for e in a.eta.split(",")):
            rows = {}
            for m in methods:
                r = run(m, path, prof, plant, tol, eta, tmp=tmp)
                rows[m] = r
                note = ""
                if m == "conservative":
                    note = f"limits x {r.info.get('conservative_scale', 1.0):.3f}"
                elif m.partition(":")[2] == "window":
                    note = (f"relaxed windows {r.info.get('relaxed_windows', 0)}, "
                            f"fallbacks {r.info.get('fallback_windows', 0)}")
                elif m.partition(":")[0] in ("pidd", "oracle", "pidd+learned"):
                    note = (f"slowed {100 * r.info.get('slowed_length_fraction', 0):.0f} % of length, "
                            f"given up {r.info.get('relaxed_samples', 0)}")
                print(f"{eta:5.2f} {m:>13} {r.cycle_s:8.3f} {r.contour_s:9.3f} "
                      f"{r.rms_gamma_um:9.2f} {1000 * (1 - eta) * tol:6.2f} {r.within:7.4f} "
                      f"{r.compute_s:9.2f}  {note}")
                sys.stdout.flush()
            print(f"      targets: {verdict(rows, tol, eta)}")


if __name__ == "__main__":
    main()
