"""End to end where the tolerance binds (issue 19, point 7): pidd as `optimize` plans it (the
offline slow-down optimizer, the profile's twin), executed on a plant drawn from the profile's
own uncertainty and judged there, against the conservative plan tuned on that plant
(benchmarks/end_to_end.py prints the whole table)."""

from __future__ import annotations

import dataclasses
import json
import warnings

import numpy as np
import pytest

from gcode_feedopt import pipeline
from gcode_feedopt.closedloop.learn import learn_logs
from gcode_feedopt.closedloop.logs import load_log
from gcode_feedopt.firmware.shaper import Shaper
from gcode_feedopt.optimize.methods import plan_schedule, vm_trajectory
from gcode_feedopt.profile import load_profile
from gcode_feedopt.profile.build import build_from_frfs
from gcode_feedopt.vm.log import write_log
from gcode_feedopt.vm.metrics import evaluate
from gcode_feedopt.vm.plant import Plant

from ..conftest import REPO
from ..foreign.machines import ForeignPlant, make_machine, with_shaper, write_dataset

BUTTERFLY = REPO / "sample_gcode" / "butterfly.gcode"


def with_limits(prof, vmax_mm_s, amax_mm_s2):
    """The profile with V and the X/Y acceleration limits (profile and firmware M201) set."""
    lim, fw = prof.limits, prof.firmware
    return dataclasses.replace(
        prof, limits=dataclasses.replace(
            lim, vmax_mm_s=vmax_mm_s, amax_mm_s2=amax_mm_s2,
            axis_amax_mm_s2=dict(lim.axis_amax_mm_s2, x=amax_mm_s2, y=amax_mm_s2)),
        firmware=dataclasses.replace(
            fw, max_accel_mm_s2=dict(fw.max_accel_mm_s2, x=amax_mm_s2, y=amax_mm_s2)))


def _run(method, path, prof, plant, tol, eta):
    sch = plan_schedule(method, path, prof, tolerance_mm=tol, stringency=eta, plant=plant)
    tr = vm_trajectory(path, sch.s_mm, sch.ts_s)
    return sch, evaluate(tr, plant.run(tr), tol)


def _butterfly(prof):
    return pipeline.path_for(pipeline.read_for(BUTTERFLY, prof), prof)


@pytest.fixture(scope="module")
def ender_fast():
    return with_limits(load_profile("ender3pro"), 150.0, 5000.0)


@pytest.mark.parametrize("eta", [0.95, 0.99])
def test_pidd_beats_conservative_by_a_quarter_and_keeps_the_tolerance(ender_fast, eta):
    """ender3pro draw (modes 42/54 Hz), butterfly at 150 mm/s, 5 m/s², E_max 0.05 mm: the
    kinematic plan breaks the tolerance (RMS γ 17.6 µm); pidd keeps RMS γ within (1 − η)·E_max
    and ≥ η of the samples within E_max on the plant, in at most 0.75 of the cycle of the
    conservative plan tuned on that very plant."""
    path = _butterfly(ender_fast)
    plant = Plant(ender_fast, seed=1)
    tol = 0.05
    _, kin = _run("kinematic", path, ender_fast, plant, tol, eta)
    assert kin.rms_gamma_mm > (1 - eta) * tol  # the tolerance binds
    cons_sch, cons = _run("conservative", path, ender_fast, plant, tol, eta)
    assert cons_sch.info["conservative_scale"] < 1.0
    sch, m = _run("pidd", path, ender_fast, plant, tol, eta)
    assert sch.info["relaxed_samples"] == 0
    assert m.rms_gamma_mm <= (1 - eta) * tol
    assert m.within_fraction >= eta
    assert m.cycle_time_s <= 0.75 * cons.cycle_time_s


@pytest.mark.shared_data
@pytest.mark.parametrize("eta", [0.90, 0.95, 0.99])
def test_pidd_keeps_the_tolerance_on_a_benchA_plant(bench_a, eta):
    """Profile built from benchA's FRFs (modes 47/37 Hz, ζ ≈ 0.07: rings for ~65 ms), a draw
    of it as the plant, butterfly at 150 mm/s, 5 m/s², E_max 0.05 mm. The slow-down optimizer
    gave up on samples whose cause window sat at its scale floor (the ringing after a hard stop
    into a slowed stretch) and ran their cells at full speed: 229–464 samples given up, RMS γ
    10.7–16.0 µm, 91–96 % within. Now none is given up and the plant keeps the tolerance."""
    prof = with_limits(bench_a[0], 150.0, 5000.0)
    path = _butterfly(prof)
    plant = Plant(prof, seed=1)
    tol = 0.05
    sch, m = _run("pidd", path, prof, plant, tol, eta)
    assert sch.info["relaxed_samples"] == 0
    assert m.rms_gamma_mm <= (1 - eta) * tol
    assert m.within_fraction >= eta


@pytest.mark.shared_data
@pytest.mark.parametrize("eta", [0.90, 0.95, 0.99])
def test_pidd_beats_conservative_by_a_quarter_on_a_benchA_plant(bench_a, eta):
    """The same lightly damped machine: slowing down around the ringing at F's 5 m/s² made
    pidd 1.42× / 1.25× / 1.07× conservative's cycle (η 0.90 / 0.95 / 0.99; two thirds of the
    length slowed); the acceleration search (optimize.methods.search_acceleration) plans at a
    lower acceleration where that is faster, and the stringency as the share of samples
    within (optimize.slowdown.budget) spends the risk where it buys time: ≤ 0.75× (measured
    0.737 / 0.653 / 0.525; with the bound on every sample 0.805 / 0.700 / 0.55), tolerance
    kept."""
    prof = with_limits(bench_a[0], 150.0, 5000.0)
    path = _butterfly(prof)
    plant = Plant(prof, seed=1)
    tol = 0.05
    cons_sch, cons = _run("conservative", path, prof, plant, tol, eta)
    assert cons_sch.info["conservative_scale"] < 1.0
    sch, m = _run("pidd", path, prof, plant, tol, eta)
    assert sch.info["accel_chosen_mm_s2"] < 5000.0
    assert sch.info["amax_mm_s2"] == sch.info["accel_chosen_mm_s2"]
    first = sch.info["accel_search"][0]
    assert first[0] == 5000.0 and sch.duration_s < first[1]
    assert m.rms_gamma_mm <= (1 - eta) * tol
    assert m.within_fraction >= eta
    assert m.cycle_time_s <= 0.75 * cons.cycle_time_s


def _foreign_pidd(seed: int, tmp_path, eta: float = 0.95, learn_first: bool = False,
                  records: list | None = None, shaper: str | None = None, stated: bool = True,
                  amax: float = 3000.0, tol: float = 0.1):
    """pidd on a machine of tests/foreign: profile built from its FRFs as `profile build`
    does, butterfly at 150 mm/s and ``amax`` (3 m/s²), E_max ``tol`` (0.1 mm), executed on its
    own physics; (schedule, metrics). ``learn_first``: the profile ``learn``s the encoder log
    (1 µm noise) of a first pidd print on that machine, and the second print is judged
    (``records``: gets learn's records). ``shaper``: the machine prints through that input
    shaper (centred, at its modes; ``with_shaper``), which the profile states unless not
    ``stated``."""
    mach = make_machine(seed)
    if shaper:
        mach = with_shaper(mach, shaper)
    write_dataset(mach, tmp_path, effects=False)
    labels = json.loads((tmp_path / "labels.json").read_text())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prof, _ = build_from_frfs(load_profile("ender3pro"),
                                  {a: sorted((tmp_path / "frf").glob(f"{a}_*.csv")) for a in "xy"},
                                  name=f"foreign-{seed}")
    prof = with_limits(prof, 150.0, amax)
    if shaper and stated:
        sh = {a: Shaper.from_dict(c) for a, c in mach.shapers.items()}
        prof = dataclasses.replace(prof, firmware=dataclasses.replace(prof.firmware,
                                                                      input_shaper=sh))
    path, plant = _butterfly(prof), ForeignPlant(mach, labels)
    if learn_first:
        sch, _ = _run("pidd", path, prof, plant, tol, eta)
        tr = vm_trajectory(path, sch.s_mm, sch.ts_s)
        act = plant.run(tr)
        noise = 0.001 * np.random.default_rng(7).standard_normal((len(act), 2))
        log = tmp_path / "first_print.csv"
        write_log(log, tr.t_s, tr.pos_mm, act + np.column_stack([noise, np.zeros(len(act))]),
                  tr.e_mm)
        prof, recs = learn_logs(prof, [load_log(log, prof)])
        if records is not None:
            records.extend(recs)
    return _run("pidd", path, prof, plant, tol, eta)


@pytest.mark.shared_data
def test_pidd_plans_a_printer_through_the_input_shaper_its_profile_states(tmp_path):
    """A belt + frame machine simulated apart from the twin (tests/foreign, seed 65: modes 41 /
    25 Hz) printing through Klipper's MZV at its modes, measured without it; butterfly at
    150 mm/s, 5 m/s², E_max 0.05 mm, η 0.95. The profile stating the shaper: pidd keeps the
    tolerance in 6.65 s; not stating it, it plans for a machine that rings more, 11.86 s (the
    same as on the machine without a shaper); the plant-tuned conservative plan takes 8.69 s."""
    sch, m = _foreign_pidd(65, tmp_path / "a", shaper="mzv", amax=5000.0, tol=0.05)
    assert m.rms_gamma_mm <= 0.05 * 0.05 and m.within_fraction >= 0.95
    _, bare = _foreign_pidd(65, tmp_path / "b", shaper="mzv", stated=False, amax=5000.0, tol=0.05)
    assert bare.rms_gamma_mm <= 0.05 * 0.05
    assert m.cycle_time_s < 0.7 * bare.cycle_time_s, (m.cycle_time_s, bare.cycle_time_s)


@pytest.mark.shared_data
def test_pidd_sees_out_the_ringing_of_a_lightly_damped_foreign_corexy(tmp_path):
    """A corexy simulated apart from the twin (tests/foreign, seed 0: belts 25.7/26.5 Hz at
    ζ 0.03, ringing ~0.9 s), profile built from its 8 noisy FRFs, butterfly at 150 mm/s,
    3 m/s², E_max 0.1 mm, η 0.95, executed on its own physics. With the slow-down's rounds
    seeing 0.3 s of history and looking back 0.5 s for a cause (enough for the built-in
    machines) the plan gave up 4,088 samples and broke the tolerance there: RMS γ 35.6 µm,
    89.3 % within. Seeing the twin's ringing out (SlowdownSettings.seeing_out) it keeps the
    tolerance with none given up."""
    sch, m = _foreign_pidd(0, tmp_path)
    assert sch.info["relaxed_samples"] == 0
    assert m.rms_gamma_mm <= 0.05 * 0.1
    assert m.within_fraction >= 0.95


@pytest.mark.shared_data
def test_pidd_waits_for_a_foreign_servo_to_settle(tmp_path):
    """A PID servo on a lead screw simulated apart from the twin (tests/foreign, seed 17),
    profile built from its 6 FRFs (1.3 % noise), butterfly at 150 mm/s, 3 m/s², E_max 0.1 mm,
    η 0.95, executed on its own physics. Its impulse response dies down in 0.13 s but its slow
    integral action settles in 0.33 s: seeing out only the ringing, the slow-down gave up 433
    samples whose cause lay further back (RMS γ 13.7 µm against 5, 99.1 % within, 38.7 s);
    seeing the settling out (twin.physics.memory_time_s) it gives none up and keeps the
    tolerance, faster."""
    sch, m = _foreign_pidd(17, tmp_path)
    assert sch.info["relaxed_samples"] == 0
    assert m.rms_gamma_mm <= 0.05 * 0.1
    assert m.within_fraction >= 0.95


@pytest.mark.shared_data
def test_pidd_keeps_the_tolerance_on_a_servo_with_a_slow_integral_pole(tmp_path):
    """A PID servo simulated apart from the twin (tests/foreign, seed 43), whose integral
    action puts a real pole at 5.9 Hz on y: with the modal fit's lag bounded at 20 ms (8 Hz)
    the twin erred 75 µm on y, its interval covered 15 %, and pidd broke the tolerance on the
    first print (RMS γ 5.05 µm against 5, 87.0 % within); learning that print made it worse
    (6.78 µm, 80.5 %). The lag now reaches the lowest measured frequency."""
    sch, m = _foreign_pidd(43, tmp_path)
    assert m.rms_gamma_mm <= 0.05 * 0.1
    assert m.within_fraction >= 0.95


@pytest.mark.slow
@pytest.mark.shared_data
@pytest.mark.parametrize("seed", [164, 16])
def test_a_stretch_no_speed_can_promise_runs_slow_not_at_full_speed(seed, tmp_path):
    """Two PID servos simulated apart from the twin whose slow integral action sits near the
    lowest measured frequency (tests/foreign, seed 164: y's real pole at 3.4 Hz below a band
    from 5 Hz, 8 FRFs at 2.4 % noise; seed 16: 2.9 / 3.3 Hz on a band from 1.5 Hz, 3 FRFs at
    2.9 %), butterfly at 150 mm/s, 5 m/s², E_max 0.05 mm, η 0.95. The twin expects stretches
    over the tolerance even with their cause window at the slow-down's floor; given up at
    full speed they ran 238 µm RMS γ (76.7 % within) on seed 164 and 25.7 µm (98.9 %) on seed
    16. Kept at the floor: within the limit, and still faster than the plant-tuned
    conservative plan (69.5 / 59.0 s).

    Whether the twin expects such stretches at all turns on the arithmetic's last bits (the
    BLAS kernels, numpy's SIMD loops): on seed 164 it gave up 14,477 samples at the floor
    with OpenBLAS's Haswell kernels, none on an Intel Xeon (2026-12-05: numpy 2.4.6, scipy
    1.17.1, OpenBLAS 0.3.31), where pidd keeps every sample within in 48.4 s; seed 16 gives
    none up on either. What must hold either way: nothing given up at rest, the tolerance
    kept, faster than the conservative plan."""
    sch, m = _foreign_pidd(seed, tmp_path, amax=5000.0, tol=0.05)
    # given up at the floor, not at rest (the report says which)
    assert sch.info["relaxed_at_rest_samples"] == 0
    assert m.rms_gamma_mm <= 0.05 * 0.05, (m.rms_gamma_mm, sch.info["relaxed_samples"])
    assert m.within_fraction >= 0.95
    assert m.cycle_time_s < {164: 69.5, 16: 59.0}[seed]


@pytest.mark.shared_data
def test_a_foreign_servos_learned_twin_carries_its_slow_dynamics_at_99_percent(tmp_path):
    """A PID servo simulated apart from the twin (tests/foreign, seed 16: 3 FRFs from 1.5 Hz,
    2.5 % noise), η 0.99, the second print planned with the first one learned.

    Which way learn's x step goes depends on the last bits of the arithmetic (the BLAS
    kernels, numpy's SIMD loops). With OpenBLAS's Haswell kernels the step, clipped to half
    by the trust region, left x 57 µm off its own print, and learn now keeps no step that
    makes that print's open-loop prediction worse (tests/closedloop/test_learn.py). On an AMD
    EPYC without AVX-512 (2026-11-28) x errs 49.6 µm on the first print and its whole step
    (13.9 σ) takes it to 6.0 µm; the next print, three times faster, erred 17.1 µm on x
    against a median σ of 5.9 µm and ran 96.91 % within (RMS γ 0.91 µm), because learn
    measured what the twin missed as a level and terms growing with the speed and the
    predicted error sample by sample, while it was slow dynamics, a filter of the command.
    Learn's residual filter (twin.residual) carries x's as variance that grows with the
    motion (y's explains under half of its held-out residual and is not kept): 16.53 s (14.35
    before; the plant-tuned conservative plan 43.5 s), 99.05 % within, RMS γ 0.21 µm; the error
    over the twin's σ has RMS 1.21 on x (2.25 before), 1.63 on y (1.74). Asserted: the
    paper's rule and 98.5 % within (y's interval is still narrow, and the share is a knife edge
    across CPUs)."""
    recs = []
    sch, m = _foreign_pidd(16, tmp_path, eta=0.99, learn_first=True, records=recs)
    assert m.rms_gamma_mm <= 0.01 * 0.1
    assert m.within_fraction >= 0.985
    for r in recs:
        assert r["prediction_rms_mm"]["after"] <= r["prediction_rms_mm"]["before"], r


def test_where_the_tolerance_does_not_bind_pidd_is_the_kinematic_plan():
    """ender3pro's own limits (70 mm/s, 3 m/s²) and a 0.2 mm tolerance: the twin predicts the
    firmware's plan inside the tolerance everywhere, and pidd is that plan, sample for sample (to 1 nm)."""
    prof = load_profile("ender3pro")
    path = _butterfly(prof)
    kin = plan_schedule("kinematic", path, prof, tolerance_mm=0.2, stringency=0.95)
    pidd = plan_schedule("pidd", path, prof, tolerance_mm=0.2, stringency=0.95)
    assert pidd.info["slowed_length_fraction"] == 0.0
    # nothing slowed: no other acceleration is tried
    assert pidd.info["accel_chosen_mm_s2"] is None and len(pidd.info["accel_search"]) == 1
    assert pidd.s_mm.size == kin.s_mm.size
    np.testing.assert_allclose(pidd.s_mm, kin.s_mm, rtol=0, atol=1e-9)


@pytest.mark.shared_data
def test_the_written_file_runs_at_the_chosen_acceleration(bench_a, tmp_path):
    """`optimize` on benchA's machine at 150 mm/s and 5 m/s² (E_max 0.05 mm, machine speeds):
    the plan chooses a lower X/Y acceleration, the file says so before its first move (M201
    and the file's M204 clamped to it, as --amax would write them) and the firmware model
    runs that file in the plan's time with the executed contour error within tolerance."""
    from gcode_feedopt.gcode.reader import read_file
    from gcode_feedopt.pipeline import Options, optimize_file

    prof = with_limits(bench_a[0], 150.0, 5000.0)
    out = tmp_path / "out.gcode"
    rep = optimize_file(BUTTERFLY, out, prof, Options(tolerance_mm=0.05, speed="machine",
                                                      allow_slower=True))
    a = rep.extra["accel_chosen_mm_s2"]
    assert a is not None and a < 5000.0
    assert rep.extra["accel_search"][0]["accel_mm_s2"] == 5000.0
    assert any("acceleration lowered to" in n for n in rep.notes)
    lines = out.read_bytes().decode().splitlines()
    first_move = next(i for i, ln in enumerate(lines) if ln.startswith(("G1 ", "G0 ")))
    assert f"M201 X{a:g} Y{a:g}" in " ".join(lines[:first_move])
    ex = rep.extra["executed"]
    assert ex["time_s"] == pytest.approx(rep.plan_time_s, rel=0.01)
    assert ex["within_fraction"] >= 0.95
    assert len(read_file(out).moves) > 2000  # a valid program
