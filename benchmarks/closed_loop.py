"""Closed loop with a disturbance the profile lacks (issue 19, point 6): print → log → learn →
print, on a machine with a fan.

The machine is a profile (``ender3pro``, or ``benchA``: built from the 12 FRFs of
../shared/data/independent/frf as ``profile build`` builds it) with its X/Y acceleration limits
raised to A (benchmarks/end_to_end.py ``with_limits``); the plant is one seeded draw of that
profile's own uncertainty plus a fan — ``periodic_time`` on one axis (default 31 Hz, 0.02 mm)
whose phase is new at every print (a fan is not phase-locked to the print) — and 1 µm of
encoder noise. The profile knows nothing of the fan.

Every round plans the butterfly with pidd as `gcode-feedopt optimize` does (the offline
slow-down optimizer and the current profile; it never sees the plant), runs the plan on the
plant, writes the encoder log, reads it back as a user's log (closedloop.logs.load_log) and
``learn``s the profile from it (closedloop.learn.learn_logs). Printed per round: cycle time,
RMS γ against (1 − η)·E_max, fraction of extruded samples within E_max, the twin's open-loop
prediction RMS on that print, and what learn wrote per axis: the level of what the twin
cannot predict (σ_r, at rest), its part growing with the commanded speed (k_v, σ = k_v·|v|) and
the RMS on that print of its residual filter (filt: what is a filter of the command, twin.residual). The conservative plan (the largest uniform scale of V and A whose run on the first
print's plant keeps RMS γ ≤ (1 − η)·E_max) is the cycle time the loop must not exceed.

Targets (issue 19): by the third print, within ≥ η and RMS γ ≤ (1 − η)·E_max, cycle ≤
conservative's.

    python benchmarks/closed_loop.py [--machine ender3pro|benchA] [--rounds 4] [--seed 1]
        [--fan x:31:0.02] [--tolerance 0.06] [--eta 0.95] [--vmax 150] [--amax 5000]
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import sys
import tempfile
import time
import warnings

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from end_to_end import BUTTERFLY, machine, with_limits  # noqa: E402

from gcode_feedopt.closedloop.learn import learn_logs  # noqa: E402
from gcode_feedopt.closedloop.logs import load_log  # noqa: E402
from gcode_feedopt.optimize.methods import plan_schedule, vm_trajectory  # noqa: E402
from gcode_feedopt.pipeline import path_for, read_for  # noqa: E402
from gcode_feedopt.vm import effects as fx  # noqa: E402
from gcode_feedopt.vm.log import write_log  # noqa: E402
from gcode_feedopt.vm.metrics import evaluate  # noqa: E402
from gcode_feedopt.vm.plant import Plant  # noqa: E402


@dataclasses.dataclass
class Round:
    k: int
    cycle_s: float
    rms_gamma_um: float
    within: float
    pred_rms_um: dict
    learned: dict
    compute_s: float
    pred_after_um: dict
    step_scale: dict
    kv_ms: dict
    filter_um: dict


def fan_plant(prof, seed: int, axis: str, freq_hz: float, amp_mm: float, phase_rad: float,
              noise_mm: float = 0.001) -> Plant:
    """The profile's draw ``seed`` with a fan of the given phase and encoder noise."""
    return Plant(prof, seed=seed, effects=[
        fx.PeriodicTime(axis, frequency_hz=freq_hz, amplitude_mm=amp_mm, phase_rad=phase_rad),
        fx.SensorNoise("x", std_mm=noise_mm), fx.SensorNoise("y", std_mm=noise_mm)])


def closed_loop(prof, path, *, rounds: int, seed: int, fan: tuple, tol: float, eta: float,
                tmp: pathlib.Path, phase_seed: int = 7, on_round=None):
    """Rounds of plan (pidd) → run → log → learn; returns (rounds, final profile)."""
    axis, f_hz, amp = fan
    phases = np.random.default_rng(phase_seed).uniform(0, 2 * np.pi, rounds)
    out = []
    for k in range(1, rounds + 1):
        plant = fan_plant(prof, seed, axis, f_hz, amp, float(phases[k - 1]))
        t0 = time.perf_counter()
        sch = plan_schedule("pidd", path, prof, tolerance_mm=tol, stringency=eta)
        dt = time.perf_counter() - t0
        tr = vm_trajectory(path, sch.s_mm, sch.ts_s)
        sim = plant.simulate(tr)
        m = evaluate(tr, sim.actual_mm, tol)
        log_path = tmp / f"round{k}.csv"
        write_log(log_path, tr.t_s, tr.pos_mm, sim.measured_mm, tr.e_mm)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            log = load_log(log_path, prof)
        prof, recs = learn_logs(prof, [log])
        pred = {r["axis"]: 1000 * r["prediction_rms_mm"]["before"] for r in recs}
        after = {r["axis"]: 1000 * r["prediction_rms_mm"]["after"] for r in recs}
        steps = {r["axis"]: r["step_scale"] for r in recs}
        kv = {r["axis"]: 1000 * r.get("noise_per_speed_s", 0.0) for r in recs}
        filt = {r["axis"]: 1000 * r.get("residual_filter_log_rms_mm", 0.0) for r in recs}
        learned = {r["axis"]: 1000 * r.get("noise_level_mm", float("nan")) for r in recs}
        r = Round(k, m.cycle_time_s, 1000 * m.rms_gamma_mm, m.within_fraction, pred, learned, dt,
                  after, steps, kv, filt)
        out.append(r)
        if on_round:
            on_round(r)
    return out, prof


def conservative_cycle(prof, path, plant, tol, eta) -> tuple[float, float]:
    sch = plan_schedule("conservative", path, prof, tolerance_mm=tol, stringency=eta, plant=plant)
    return (sch.s_mm.size - 1) * sch.ts_s, float(sch.info["conservative_scale"])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--machine", default="ender3pro")
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1, help="plant draw")
    ap.add_argument("--fan", default="x:31:0.02", help="axis:frequency_hz:amplitude_mm")
    ap.add_argument("--tolerance", type=float, default=0.06)
    ap.add_argument("--eta", type=float, default=0.95)
    ap.add_argument("--vmax", type=float, default=150.0)
    ap.add_argument("--amax", type=float, default=5000.0)
    a = ap.parse_args(argv)
    ax, f_hz, amp = a.fan.split(":")
    fan = (ax, float(f_hz), float(amp))
    prof = with_limits(machine(a.machine), a.vmax, a.amax)
    path = path_for(read_for(BUTTERFLY, prof), prof)
    tmp = pathlib.Path(tempfile.mkdtemp())
    cons_s, scale = conservative_cycle(prof, path, fan_plant(prof, a.seed, *fan, 0.0), a.tolerance, a.eta)
    lim = 1000 * (1 - a.eta) * a.tolerance
    print(f"{a.machine} draw seed {a.seed} + fan {fan[0]} {fan[1]:g} Hz {fan[2]:g} mm (random phase "
          f"per print), butterfly, V {a.vmax:g} mm/s, A {a.amax:g} mm/s², E_max {a.tolerance:g} mm, "
          f"η {a.eta:g}; conservative {cons_s:.3f} s (limits x {scale:.3f})")
    print(f"{'print':>5} {'cycle s':>8} {'RMS γ µm':>9} {'limit':>6} {'within':>7} "
          f"{'pred x µm':>9} {'pred y µm':>9} {'level x µm':>10} {'level y µm':>10} "
          f"{'k_v x ms':>8} {'k_v y ms':>8} {'filt x µm':>9} {'filt y µm':>9} {'plan s':>7}"
          f"  learned step (prediction RMS after, µm)")

    def show(r):
        print(f"{r.k:5d} {r.cycle_s:8.3f} {r.rms_gamma_um:9.2f} {lim:6.2f} {r.within:7.4f} "
              f"{r.pred_rms_um.get('x', np.nan):9.1f} {r.pred_rms_um.get('y', np.nan):9.1f} "
              f"{r.learned.get('x', np.nan):10.1f} {r.learned.get('y', np.nan):10.1f} "
              f"{r.kv_ms.get('x', np.nan):8.3f} {r.kv_ms.get('y', np.nan):8.3f} "
              f"{r.filter_um.get('x', np.nan):9.1f} {r.filter_um.get('y', np.nan):9.1f} "
              f"{r.compute_s:7.2f}  "
              + ", ".join(f"{a} x{r.step_scale[a]:.2g} ({r.pred_after_um[a]:.1f})" for a in r.step_scale))
        sys.stdout.flush()

    rows, _ = closed_loop(prof, path, rounds=a.rounds, seed=a.seed, fan=fan, tol=a.tolerance,
                          eta=a.eta, tmp=tmp, on_round=show)
    for r in rows[2:]:
        ok = r.within >= a.eta and r.rms_gamma_um <= lim and r.cycle_s <= cons_s
        print(f"print {r.k}: within {r.within:.4f} ≥ {a.eta:g}, RMS γ {r.rms_gamma_um:.2f} ≤ {lim:.2f} µm, "
              f"cycle {r.cycle_s:.3f} ≤ {cons_s:.3f} s: {'met' if ok else 'NOT met'}")


if __name__ == "__main__":
    main()
