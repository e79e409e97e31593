"""The twin and the diagnosis on machines of structures we did not simulate (tests/foreign/
machines.py), built and judged as a user would: `profile build` from the machine's FRF files,
then the logs. Each case is one the twin got wrong before the fix it names."""

from __future__ import annotations

import dataclasses
import json
import sys
import warnings

import numpy as np
import pytest

from gcode_feedopt.closedloop.diagnose import diagnose_log
from gcode_feedopt.closedloop.logs import MotionLog, log_warmup
from gcode_feedopt.profile import load_profile
from gcode_feedopt.profile.build import build_from_frfs
from gcode_feedopt.twin.modal import ZETA_MIN
from gcode_feedopt.twin.model import axis_twin
from gcode_feedopt.twin.physics import axis_impulse, axis_modal

from .machines import BENCH_A, make_machine, write_dataset

pytestmark = pytest.mark.skipif(not BENCH_A.is_dir(), reason="needs ../shared/data/independent")


def _set(tmp_path_factory, seed, effects, fan_hz=None, n_meas=None, kind=None):
    out = tmp_path_factory.mktemp(f"foreign{seed}")
    # "more": the clean logs and the drive's effect logs (machines._more_effects) only;
    # "variants": the clean logs and machines._variant_effects's
    more = effects == "more"
    variants = effects == "variants"
    mach = make_machine(seed, kind)
    if n_meas:  # the machine measured this many times instead of its own draw's
        mach = dataclasses.replace(mach, n_meas=n_meas)
    labels = write_dataset(mach, out, effects=effects is True, fan_hz=fan_hz,
                           more_effects=more, variants=variants)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        prof, _ = build_from_frfs(load_profile("ender3pro"),
                                  {a: sorted((out / "frf").glob(f"{a}_*.csv")) for a in "xy"},
                                  name=f"foreign-{seed}")
    return out, labels, prof


def _log(out, prof, name):
    a = np.loadtxt(out / "logs" / name, delimiter=",", skiprows=1)
    cmd = np.column_stack([a[:, 1:3], np.zeros(len(a))])
    pos = np.column_stack([a[:, 3:5], np.zeros(len(a))])
    w0 = log_warmup(cmd[:, :2], prof.ts_s, prof)
    return MotionLog(ts_s=prof.ts_s, cmd_mm=cmd, pos_mm=pos, source=name, kind="encoder", warmup=w0)


def _named(made, kind, source=None):
    """(truth, the diagnosis's effect of that kind on its axis or None, Diagnosis) of the
    data set's first log whose one effect is ``kind`` (and, given, whose physics has that
    ``source``)."""
    out, labels, prof = made
    e = next(e for e in labels["logs"] if e["effects"][0]["kind"] == kind
             and source in (None, e["effects"][0].get("physics", {}).get("source")))
    truth = e["effects"][0]
    d = diagnose_log(_log(out, prof, e["file"].split("/")[-1]), prof)
    g = next((g for g in d.effects if g["kind"] == kind and g["axis"] == truth["axis"]), None)
    return truth, g, d


def _fan_alone_named(made, amplitude_rel):
    """The data set's fan log names its fan alone: frequency within 0.1 Hz, amplitude within
    ``amplitude_rel``; returns the Diagnosis."""
    truth, g, d = _named(made, "periodic_time")
    assert g is not None, (truth, d.effects)
    assert abs(g["params"]["frequency_hz"] - truth["params"]["frequency_hz"]) < 0.1, g
    tv = truth["params"]["amplitude_mm"]
    assert abs(g["params"]["amplitude_mm"] - tv) <= amplitude_rel * tv, (truth, g)
    assert [e["kind"] for e in d.effects] == ["periodic_time"], d.effects
    assert d.effects[0]["form"] == "time", d.effects  # running throughout, not switched on
    return d


def _clean_diagnoses(made):
    """(file, effects named beside the data set's inherent ones, Diagnosis) of each clean log
    of a data set made by ``dataset``."""
    out, labels, prof = made
    inherent = {(e["kind"], e["axis"]) for e in labels["inherent"]}
    for e in labels["logs"]:
        if e["effects"][0]["kind"] != "none":
            continue
        d = diagnose_log(_log(out, prof, e["file"].split("/")[-1]), prof)
        yield e["file"], [g for g in d.effects if g["kind"] != "none"
                          and (g["kind"], g["axis"]) not in inherent], d


def _rms(v):
    return float(np.sqrt(np.mean(np.square(v))))


def _slowest_real_pole_hz(which: str, axis: str) -> float:
    """The slowest real pole of data set ``which``'s machine on ``axis``, Hz (a servo's
    integral action)."""
    A, _, _ = make_machine(SETS[which][0]).chans[axis].ss()
    return min(abs(e.real) for e in np.linalg.eigvals(A) if abs(e.imag) < 1e-6) / (2 * np.pi)


#: The data sets the tests use: name -> (seed, with effect logs (True, False or "more": the
#: drive's effects instead)[, fan Hz]), each made once per module.
SETS = {
    # PID servo on a lead screw, 0.9 ms transport delay, 8 FRFs from 3 Hz in 2 Hz steps
    "servo4": (4, False),
    # PID servo, 6 FRFs from 1 Hz in 0.5 Hz steps, 2.8 % noise
    "servo8": (8, False),
    # PID servo whose modal fit leaves a 6–10 µm lead on y: a lead is not friction
    "servo5": (5, False),
    # belt + frame + a hotend on a flexible mount sensed at the nozzle: three modes
    "hotend1": (1, True),
    # belt + frame, x 50.5 Hz ζ 0.026 whose 6 FRFs (2 Hz steps, 3 % noise) put it at 49.0–50.4 Hz
    "belt11": (11, True),
    # a corexy whose belts differ: its cross-talk is inherent (cross_coupling is there)
    "corexy13": (13, False),
    # corexy, belts 25.7/26.5 Hz ζ 0.03 (0.5 Hz steps): its cross-talk rings at the belts
    "corexy0": (0, False),
    # corexy, belts 35.7/36.9 Hz measured in 2 Hz steps: members cannot all resolve them
    "corexy18": (18, False),
    # belt + frame, y 41.9 Hz ζ 0.05, and a fan on y at 41 Hz: inside the mode's band
    "fan23": (23, True, 41.0),
    # belt + frame and belt + hotend with the drive's effects (a dead band, an eccentricity,
    # a Coulomb friction, a frame pushed by the other axis)
    "belt14more": (14, "more"),
    "hotend21more": (21, "more"),
    # PID servo (seed 8) with the drive's effects: its integrator washes a friction out
    "servo8more": (8, "more"),
    # PID servo, 6 FRFs from 3 Hz in 1 Hz steps, 1.3 % noise, whose members put y's
    # near-critically damped low mode anywhere in 4–9 Hz
    "servo17": (17, False),
    # PID servo, 4 FRFs from 2 Hz in 0.5 Hz steps, 2.8 % noise, whose members fit the slow
    # poles four ways around a 19.2 Hz, ζ 0.43 loop mode
    "servo31": (31, False),
    # PID servo whose resonance shift came with a 0.2 ms "delay", the scan's smallest
    "servo25": (25, True),
    # PID servos with the drive's effects whose twins' lag is off by −0.09 / +0.12 ms
    "servo5more": (5, "more"),
    "servo19more": (19, "more"),
    # PID servo whose integral action puts a real pole at 5.9 Hz on y and 8.4 Hz on x, 8 FRFs
    # from 2 Hz in 0.5 Hz steps: a lag bounded at 20 ms (8 Hz) could not reach it
    "servo43": (43, True),
    # PID servo whose integral action puts a real pole at 7.3 Hz on x (τ 21.8 ms, just beyond
    # the lag's 20 ms bound), 8 FRFs from 3 Hz in 2 Hz steps, 2.1 % noise
    "servo58": (58, True),
    # belt + hotend whose y mode (32.1 Hz, ζ 0.023) still rings at 1 % after the 1 s memory
    "hotend305": (305, False),
    # PID servo, 3 FRFs from 1 Hz in 1 Hz steps, 2.5 % noise: its members kept the set's lag
    # (−0.47 … −0.80 ms where the machine has none) along a direction the data do not fix
    "servo329": (329, False),
    # PID servo, 4 FRFs from 1 Hz in 2 Hz steps, 2.7 % noise: the integral action's pole (4.0
    # Hz) beside its zero (3.4 Hz), which one member put at 0.18 Hz by overdamping a pair
    "servo334": (334, False),
    # belt + frame, x 34.6 Hz ζ 0.030 whose 7 FRFs put it at 33.8–35.5 Hz, a fan on x at 24.5 Hz
    "belt343": (343, True),
    # PID servo whose twin's mean misses x's integral-action doublet by 84–161 µm RMS
    "servo334fan": (334, True),
    # PID servo, 6 FRFs from 3 Hz in 2 Hz steps, 2.3 % noise: x's integral action (a real pole
    # at 15.6 Hz) lifts |H| to 1.025 at 3 Hz, which the set's own fit took as a 4.5 Hz pair
    # overdamped to a real pole at 1.2 Hz
    "servo347": (347, False),
    # PID servo, 3 FRFs from 5 Hz in 0.5 Hz steps, 2.6 % noise, whose integral action's real
    # pole sits below the band, at 3.03 Hz on y
    "servo85": (85, False),
    # PID servo, 7 FRFs from 5 Hz in 1 Hz steps, 1.0 % noise: y's integral action puts a
    # real pole at 7.85 Hz, which the set's fit overdamped to a pole at 2.9 Hz
    "servo238": (238, False),
    # PID servo, 3 FRFs from 1.5 Hz in 1 Hz steps, 2.9 % noise: real poles at 2.9 Hz (x) and
    # 3.3 Hz (y), which the set's fit put at 1.2 and 1.0 Hz
    "servo16": (16, False),
    # PID servo, 4 FRFs from 5 Hz in 0.5 Hz steps, 2.5 % noise: y's integral action puts a
    # real pole at 3.67 Hz, below the band, which a lag bounded at a pole at f₀ could not reach
    "servo367": (367, False),
    "corexy610more": (610, "more"),
    "servo606more": (606, "more"),
    # corexy, belts 31.1/30.2 Hz ζ 0.09, four FRFs in 2 Hz steps: a friction on y was named a
    # backlash (the fit part's leader), the held-out part preferring the friction by far
    "corexy626more": (626, "more"),
    # belt + hotend, x 23.4 Hz ζ 0.079 in four FRFs 2 Hz apart: a 2.7 µm "fan" at 22.9 Hz was
    # named after a friction on x
    "hotend624more": (624, "more"),
    # PID servo, 7 FRFs from 1.5 Hz in 0.5 Hz steps, 1.1 % noise: x's integral action (a real
    # pole at 6.1 Hz); a member's silenced 89 Hz term freed its slow pair to a pole at 0.39 Hz
    "servo362": (362, False),
    # belt + frame, x 63.3 Hz ζ 0.059, y 54.4 Hz ζ 0.102, 5 FRFs from 1.5 Hz in 2 Hz steps:
    # a fan switched on during a rose; two eccentricities on one axis
    "belt700variants": (700, "variants"),
    # belt + hotend, x 29.9 Hz: the variants' friction of the carriage's own velocity on x
    "hotend708variants": (708, "variants"),
    "hotend711variants": (711, "variants"),
    # belt + frame, x 30.3 Hz ζ 0.034, y 41.9 Hz: y's frame pushed by x's carriage, which rings
    "belt23more": (23, "more"),
    # belt + hotend, x 26.8 Hz ζ 0.047, 3 FRFs in 0.5 Hz steps, 2.6 % noise, sensor σ 1.9 µm
    "hotend805": (805, True),
    # belt + hotend, y 33.6 Hz ζ 0.039, 6 FRFs in 2 Hz steps: a fan at 34.9 Hz on y
    "hotend804": (804, True),
    # belt + frame, x 36.3 Hz ζ 0.075: a fan at 32.2 Hz on x switched on during a rose
    "belt712variants": (712, "variants"),
    # belt + hotend, y 24.4 Hz ζ 0.023: a fan at 21.5 Hz on y switched on during a rose
    "hotend722variants": (722, "variants"),
    # belt + hotend, x 26.9 Hz ζ 0.032, frame 73.8 Hz: x's frame pushed by y's carriage
    "hotend802more": (802, "more"),
    # belt + hotend, x's frame pushed as y's motor is commanded
    "hotend1more": (1, "more"),
    # PID servos whose fits have no real pole: 901 x as two pairs at 16.1 / 18.7 Hz, ζ 0.84 /
    # 0.82; 902 y measured from 5 Hz, its loop at 47.4 Hz, ζ 0.41
    "servo901more": (901, "more"),
    "servo902more": (902, "more"),
    # PID servos whose table 1.25–1.4 times heavier moves the loop (ModalModel.loaded): 900 x
    # 50.3 Hz ζ 0.74, 901 x 15.9 Hz ζ 0.82, 902 x 40.2 Hz ζ 0.45
    "servo900": (900, True),
    # the same servo with the drive's effects: its table's friction through the loop
    "servo900more": (900, "more"),
    # PID servo 905 (x 23.3 Hz ζ 0.47, y 44.3 Hz ζ 0.78), the drive's effects: y's table
    # pushed as x is commanded
    "servo905more": (905, "more"),
    # PID servo 906 (x 26.7 Hz ζ 0.54), the drive's effects: x's table's friction
    "servo906more": (906, "more"),
    "servo901": (901, True),
    "servo902": (902, True),
}
#: sets whose machine is drawn as another kind than its seed's own: name -> kind
KIND = {
    # corexy, belts 38.9/38.2 Hz ζ 0.026 measured in 2 Hz steps: the plant's belts off the
    # twin's leave a ring that drifts in phase; a 2.7 µm "fan" at 37.9 Hz was named on log_02
    "corexy610more": "corexy",
    # PID servo, loop mode 21.7 Hz ζ 0.40: an 11.9 µm screw eccentricity of λ 4.22 mm on a
    # Benchy layer (v/λ 4–33 Hz, across the loop) was none
    "servo606more": "servo_screw",
}
#: sets measured once (one FRF per axis): name -> (seed, effects)
ONCE = {
    # belt + hotend, its 2–150 Hz FRF once: clean logs covered ≥ 89.1 % by the measured spread
    "hotend1once": (1, False),
    # PID servo, its 3–229.5 Hz FRF once: clean logs covered ≥ 17.9 %
    "servo4once": (4, False),
    # corexy, its FRF once: log_03 was named a resonance shift of y to 56.4 Hz
    "corexy3once": (3, False),
}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    made = {}

    def get(name):
        if name not in made:
            if name in ONCE:
                seed, effects = ONCE[name]
                made[name] = _set(tmp_path_factory, seed, effects=effects, n_meas=1)
            else:
                seed, effects, *fan = SETS[name]
                made[name] = _set(tmp_path_factory, seed, effects=effects,
                                  fan_hz=(fan or [None])[0], kind=KIND.get(name))
        return made[name]

    return get


@pytest.mark.parametrize("which", ["servo334", "servo347"])
def test_no_member_puts_a_pole_below_the_band_by_overdamping_a_pair(which, dataset):
    """servo334, x: the set's fit puts the integral action's doublet at 4.2 Hz, ζ 0.94 (the
    machine: a real pole at 4.0 Hz beside a zero at 3.4). One member, fitted from it, kept
    the pair's frequency in the band (1.0 Hz, the lowest measured) but took its damping to
    2.8: a real pole at 0.18 Hz, nothing measured below 1 Hz to confirm it, for 2 % less
    misfit. That member trailed the command by −27 ms (the machine: 0.14 ms), the twin, the
    members' mean, erred 180–205 µm RMS on clean butterflies where "actual = command" errs
    245–311, and a pidd plan broke the tolerance 90-fold on the machine (twin.modal.fit_modal:
    such a member is fitted again with its poles in the band).

    servo347, x: the same in the set's own fit, from which every member starts: a pair at
    4.5 Hz overdamped to ζ 2.0, a real pole at 1.2 Hz where the machine's is at 15.6 Hz
    (band from 3 Hz). Four of the six members went on to 0.5–1.5 Hz, the twin erred 81–129 µm
    RMS on clean logs where "actual = command" errs 61–97, and the first pidd print broke the
    tolerance (RMS γ 36.7 µm against 2.5, 93.1 % within E_max at η 0.95). ``_widen`` no
    longer takes a pair past ζ 1 where that puts a pole below half the band (``POLE_FLOOR``)."""
    out, _, prof = dataset(which)
    for ax in "xy":
        f0 = float(prof.axes[ax].frf.freq_hz[prof.axes[ax].frf.freq_hz > 0][0])
        for m in axis_modal(prof, ax, warn=False).models:
            assert m.slowest_pole_hz >= f0 * (1 - 1e-9), (ax, m.freq_hz, m.damping)
            assert abs(m.lag_s_total) < 0.01, (ax, m.lag_s_total)
    for name in ("log_01.csv", "log_02.csv", "log_03.csv"):
        log = _log(out, prof, name)
        mean, _ = axis_twin(prof, "x").run(log.cmd_mm[:, 0], log.pos_mm[:, 0], learn=False)
        err = _rms(log.pos_mm[:, 0] - mean)
        assert err < 0.65 * _rms(log.pos_mm[:, 0] - log.cmd_mm[:, 0]), (name, err)


@pytest.mark.slow
def test_a_pole_a_little_below_the_band_stands(dataset):
    """servo85, y: the machine's slow real pole is at 3.03 Hz, the band starts at 5 Hz. Its
    members put it at 2.5–3.3 Hz, below the band but above half of it (``POLE_FLOOR``); held
    in the band they put it at 6.3–7.1 Hz and the first pidd print broke the tolerance (3.8 µm
    RMS γ against 2.5, 93.6 % within at η 0.95, E_max 0.05 mm)."""
    _, _, prof = dataset("servo85")
    slow = _slowest_real_pole_hz("servo85", "y")
    f0 = float(prof.axes["y"].frf.freq_hz[0])
    assert slow < f0
    for m in axis_modal(prof, "y", warn=False).models:
        assert abs(m.slowest_pole_hz / slow - 1) < 0.25, (slow, m.freq_hz, m.damping)


@pytest.mark.slow
@pytest.mark.parametrize("which, axis", [("servo238", "y"), ("servo16", "x"), ("servo16", "y")])
def test_a_pole_below_the_band_only_where_the_data_demand_it(which, axis, dataset):
    """servo238, y: the machine's slow real pole is at 7.85 Hz, the band starts at 5 Hz; the
    set's fit took a pair past ζ 1 to a pole at 2.9 Hz (above half the band) for a drop of
    the residual the held fit matches within noise, and five of its seven members followed
    to 2.5–2.9 Hz. servo16: poles at 2.9 / 3.3 Hz, band from 1.5 Hz, put at 1.2 / 1.0 Hz; its
    members went to 0.5–1.7 Hz and the first pidd print broke the tolerance (281 µm RMS γ,
    68 % within at η 0.95). ``_widen`` now holds the pole at f₀ unless leaving it below
    explains the data significantly better (``BELOW_BAND_CHI2``); servo85's pole at 3.0 Hz
    below a band from 5 Hz still stands (test_a_pole_a_little_below_the_band_stands)."""
    out, _, prof = dataset(which)
    slow = _slowest_real_pole_hz(which, axis)
    f0 = float(prof.axes[axis].frf.freq_hz[0])
    assert f0 < slow
    poles = [m.slowest_pole_hz for m in axis_modal(prof, axis, warn=False).models]
    assert min(poles) >= f0 * (1 - 1e-3), poles
    if which == "servo238":  # 7 FRFs at 1 % noise: the held fit finds the machine's pole
        assert abs(np.median(poles) / slow - 1) < 0.05, (slow, poles)
    i = "xy".index(axis)
    for name in ("log_01.csv", "log_02.csv", "log_03.csv"):
        log = _log(out, prof, name)
        mean, _ = axis_twin(prof, axis).run(log.cmd_mm[:, i], log.pos_mm[:, i], learn=False)
        err = _rms(log.pos_mm[:, i] - mean)
        assert err < 0.5 * _rms(log.pos_mm[:, i] - log.cmd_mm[:, i]), (name, err)


@pytest.mark.slow
def test_a_lag_below_the_band_where_the_data_demand_it(dataset):
    """servo367, y: the integral action's pole at 3.67 Hz, the band from 5 Hz. The lag stopped
    at a pole at f₀ (31.8 ms) in every member, the twin erred 63 µm RMS on the first pidd
    plan where "actual = command" errs 79, its 95 % interval covered 37 %, and that print
    kept 91.2 % within at η 0.95. Past f₀ the lag may go to a pole at ``POLE_FLOOR``·f₀ where
    that one bound's likelihood ratio beats ``BELOW_BAND_CHI2``, as a pair's pole may."""
    out, _, prof = dataset("servo367")
    slow = _slowest_real_pole_hz("servo367", "y")
    f0 = float(prof.axes["y"].frf.freq_hz[0])
    assert slow < f0
    poles = [1 / (2 * np.pi * m.lag_s) for m in axis_modal(prof, "y", warn=False).models]
    assert max(poles) < f0 and abs(np.median(poles) / slow - 1) < 0.2, (slow, poles)
    for name in ("log_01.csv", "log_02.csv", "log_03.csv"):
        log = _log(out, prof, name)
        mean, std = axis_twin(prof, "y").run(log.cmd_mm[:, 1], log.pos_mm[:, 1], learn=False)
        err = _rms(log.pos_mm[:, 1] - mean)
        assert err < 0.5 * _rms(log.pos_mm[:, 1] - log.cmd_mm[:, 1]), (name, err)
        assert np.mean(np.abs(log.pos_mm[:, 1] - mean) <= 1.96 * std) > 0.9, name


@pytest.mark.slow
def test_a_silenced_mode_frees_no_pole_below_the_band(dataset):
    """servo362, x: band from 1.5 Hz, the integral action's pole at 6.1 Hz. A member whose
    lightly damped 89 Hz term sank to the damping floor was refitted without it, and that
    refit took its 9 Hz pair to a pole at 0.39 Hz, past the rule every other member keeps; the
    first pidd print took 29.5 s where the plant-tuned conservative plan takes 25.9."""
    out, _, prof = dataset("servo362")
    f0 = float(prof.axes["x"].frf.freq_hz[0])
    poles = [m.slowest_pole_hz for m in axis_modal(prof, "x", warn=False).models]
    assert min(poles) >= f0 * (1 - 1e-3), poles
    for name in ("log_01.csv", "log_02.csv", "log_03.csv"):
        log = _log(out, prof, name)
        mean, std = axis_twin(prof, "x").run(log.cmd_mm[:, 0], log.pos_mm[:, 0], learn=False)
        err = _rms(log.pos_mm[:, 0] - mean)
        assert err < 0.5 * _rms(log.pos_mm[:, 0] - log.cmd_mm[:, 0]), (name, err)


def test_a_lag_the_data_do_not_fix_is_uncertain_not_wrong(dataset):
    """servo329: its three x members, each fitted from the set's fit, kept its lag (−0.47,
    −0.65, −0.80 ms; the machine's integral action leaves none at constant speed), and the
    prior twin erred 43–58 µm RMS on clean butterflies with a 95 % interval that covered
    30–57 %. With each fit's own covariance (twin.modal.fit_covariance) the lag is uncertain
    by more than it is off, and the interval covers the machine."""
    out, _, prof = dataset("servo329")
    ir = axis_impulse(prof, "x")
    k = np.arange(prof.twin.n_taps) * prof.ts_s
    lag, sd = float(k @ ir.mean), float(np.linalg.norm(k @ ir.factor))
    assert abs(lag) < 1.5 * sd, (lag, sd)
    models = axis_modal(prof, "x", warn=False).models
    assert np.ptp([m.lag_s_total for m in models]) < 0.5 * sd  # the spread alone misses it
    for name in ("log_01.csv", "log_02.csv", "log_03.csv"):
        log = _log(out, prof, name)
        mean, std = axis_twin(prof, "x").run(log.cmd_mm[:, 0], log.pos_mm[:, 0], learn=False)
        inside = float(np.mean(np.abs(log.pos_mm[:, 0] - mean) <= 1.96 * std))
        assert inside > 0.93, (name, inside)


@pytest.mark.parametrize("which", ["servo4", "servo8", "servo43"])
def test_prior_prediction_of_a_servo_beats_actual_equals_command(which, dataset):
    """Before: seed 4 y erred 1139 µm RMS (two members put a mode below the band), seed 8 y
    100 µm (the closed loop's real poles forced into ζ ≤ 0.9), seed 43 y 75.5 µm (its slow
    real pole beyond the lag's old 20 ms bound), against 386 / 377 / 288 µm for
    'actual = command'."""
    out, _, prof = dataset(which)
    log = _log(out, prof, "log_01.csv")
    for i, ax in enumerate("xy"):
        mean, _ = axis_twin(prof, ax).run(log.cmd_mm[:, i], log.pos_mm[:, i], learn=False)
        twin = _rms(log.pos_mm[:, i] - mean)
        none = _rms(log.pos_mm[:, i] - log.cmd_mm[:, i])
        assert twin < 0.1 * none, (which, ax, twin, none)


def test_no_member_mode_below_the_measured_band(dataset):
    out, _, prof = dataset("servo4")
    for ax in "xy":
        f0 = float(prof.axes[ax].frf.freq_hz[0])
        for m in axis_modal(prof, ax, warn=False).models:
            assert m.freq_hz.min() >= f0 * (1 - 1e-9), (ax, m.freq_hz)


@pytest.mark.parametrize("which, axes", [("servo43", "xy"), ("servo58", "x")])
def test_a_servos_slow_real_pole_is_fitted_where_it_is(which, axes, dataset):
    """A PID loop's integral action puts a real pole (with a zero beside it) a few Hz up: on
    seed 43 at 5.94 Hz (y) and 8.36 Hz (x), the eigenvalues of its own physics. With the lag
    bounded at 20 ms (a pole at ≥ 8 Hz) every member's y fit sat on the bound, the data's DC
    gain read 1.018 and the twin erred 75 µm RMS on a butterfly; the lag may now reach the
    lowest measured frequency (below it only where the data demand it: test_a_lag_below_
    the_band_where_the_data_demand_it). Seed 58 x: 7.3 Hz, 9 % beyond the bound, where the
    data said so at p = 0.0014 (twin.modal, ``_reach_lag``): on the bound (7.96 Hz) its twin
    erred 23–31 µm (its y's slow pole, at 14.3 Hz, is a pair of real poles with the loop's,
    not the lag)."""
    out, _, prof = dataset(which)
    for ax in axes:
        slow = _slowest_real_pole_hz(which, ax)
        f0 = float(prof.axes[ax].frf.freq_hz[0])
        poles = [1 / (2 * np.pi * m.lag_s) for m in axis_modal(prof, ax, warn=False).models]
        assert min(poles) >= f0 * (1 - 1e-9), (ax, poles)
        assert abs(np.median(poles) / slow - 1) < 0.05, (ax, slow, poles)


def test_prior_prediction_where_members_cannot_resolve_two_close_modes(dataset):
    """corexy18: three of eight members per axis put one of the two belt modes (35.7/36.9 Hz,
    2 Hz steps) at the damping floor, a line that rings for seconds: the twin's mean erred
    124 µm RMS on y of log_01 where 'actual = command' errs 77 µm (twin.modal,
    ``_silence_unresolved``). The cross-talk of its belts stays (no per-axis FRF holds it)."""
    out, _, prof = dataset("corexy18")
    for ax in "xy":
        for m in axis_modal(prof, ax, warn=False).models:
            floor = m.damping <= ZETA_MIN * 1.05
            assert not np.any((m.b0[floor] != 0) | (m.b1_rad_s[floor] != 0)), (ax, m)
    for name in ("log_01.csv", "log_02.csv", "log_03.csv"):
        log = _log(out, prof, name)
        for i, ax in enumerate("xy"):
            mean, _ = axis_twin(prof, ax).run(log.cmd_mm[:, i], log.pos_mm[:, i], learn=False)
            twin = _rms(log.pos_mm[:, i] - mean)
            none = _rms(log.pos_mm[:, i] - log.cmd_mm[:, i])
            assert twin < 0.6 * none, (name, ax, twin, none)


def test_a_mode_ringing_past_the_memory_leaves_the_lag_right(dataset):
    """hotend305: with the memory's tail folded onto tap 0 its seven y members' lags came out
    −2.0 … 12.4 ms where each trails by 1.69 ms, and the prior twin erred 99.5 / 63.4 µm RMS
    on y of the clean butterfly and rose where 'actual = command' errs 163 / 181 µm (pidd then
    broke E_max 0.05 mm at η 0.95: 93.3 % within). Folded keeping the first moment
    (twin.modal, ``_fold_tail``): 9.4 / 13.8 µm."""
    out, _, prof = dataset("hotend305")
    k = np.arange(prof.twin.n_taps) * prof.ts_s
    for ax in "xy":
        models = axis_modal(prof, ax, warn=False).models
        lags = np.array([k @ m.impulse(prof.ts_s, prof.twin.n_taps) for m in models])
        np.testing.assert_allclose(lags, [m.lag_s_total for m in models], atol=1e-12)
        assert np.ptp(lags) < 0.02 * np.mean(lags), (ax, lags)
    for name in ("log_01.csv", "log_02.csv"):
        log = _log(out, prof, name)
        mean, _ = axis_twin(prof, "y").run(log.cmd_mm[:, 1], log.pos_mm[:, 1], learn=False)
        twin = _rms(log.pos_mm[:, 1] - mean)
        none = _rms(log.pos_mm[:, 1] - log.cmd_mm[:, 1])
        assert twin < 0.15 * none, (name, twin, none)


@pytest.mark.parametrize("which", ["servo4", "servo8", "hotend1", "belt11", "corexy13",
                                   "corexy0", "corexy18", "servo5", "servo43", "servo58",
                                   "servo17", "servo31", "servo329", "servo334"])
def test_clean_logs_of_a_plant_inside_the_spread_are_none(which, dataset):
    """belt11: every clean log was named a resonance_shift x to 49.7 Hz, a move of the
    lightly damped mode inside the members' own band that the draw's first-order directions
    cannot follow (diagnose._absorb_mode). corexy13: after its belt cross-talk was named, the
    same move was named on log_03 (57.8 Hz): the bar holds in every round. corexy0 and
    corexy18: the belts' cross-talk rings at their modes, and a sinusoid of fixed phase fitted
    that ring lap after lap — a 43 µm and a 4.9 µm "fan" at 25.2 and 34.4 Hz
    (diagnose._ring_bar). servo5: the 6–10 µm lead its modal fit leaves on y was named
    "friction −0.010 mm" on two of three logs; friction only lags (diagnose._candidates).
    servo43: the 76–90 µm its twin erred on y (the slow pole out of the lag's reach) was named
    a 0.12 mm fan on log_02. servo58: the 23–31 µm its twin erred on x (its slow pole 9 %
    beyond the lag's bound) was named a resonance shift to 15.2 Hz on every clean log.
    servo17: its members fit the loop's slow poles as pairs in different orders, and the
    representative model averaged index by index made a 7.0 Hz, ζ 0.98 "dominant mode" of
    them, whose −0.6 % move took 1.6 of the 2.1 µm the draw leaves on y: "resonance_shift y
    6.99 Hz" was named on two of three clean logs under one BLAS kernel's last bits (OpenBLAS on
    an AMD EPYC), on none under another's (AxisModal.mean_model matches modes now). On an AMD
    EPYC without AVX-512, log_01 then had "friction y 0.027 mm" named in the integral form
    with τ_i 5 ms, the lowest end of its scan (catalogue._friction: not resolved now).
    servo31: log_02 had "resonance_shift x 19.02 Hz" named, a −0.7 % move of the loop mode
    its four members put at 18.94–19.33 Hz, 1.05 times the furthest member's deviation and
    0.47 times the bound of one more member (AxisPhysics.move_inside_spread)."""
    made = dataset(which)
    inherent = made[1]["inherent"]
    for name, named, d in _clean_diagnoses(made):
        assert not named, (which, name, named)
        if not inherent:  # a corexy's cross-talk leaves more than its noise (docs/diagnose.md)
            left = {ax: lo["rms_mm"] / lo["noise_mm"] for ax, lo in d.leftover.items()
                    if lo["significant"]}
            assert not left, (which, name, left)


@pytest.mark.slow
def test_a_corexys_belts_placed_off_ring_no_fan(dataset):
    """corexy610 (belts 38.9/38.2 Hz, ζ 0.026, five FRFs in 2 Hz steps): the log's belts sit
    a little off the twin's, and what that leaves rings at the belts with a phase that drifts
    along each ring (the derivative of a mode's response in its frequency, t·e^(−ζωt)·sin).
    A sinusoid of fixed phase fitted it on log_02 (a rose, whose accelerations recur lap
    after lap): "periodic_time x 37.9 Hz, 2.7 µm" on a clean log. The ring a fan must beat
    near a mode holds that term too (diagnose._ring_bar); no clean log names anything but
    the belts' cross-talk."""
    for name, named, _ in _clean_diagnoses(dataset("corexy610more")):
        assert not named, (name, named)


@pytest.mark.slow
def test_an_eccentricity_through_a_servos_loop_is_named(dataset):
    """servo606 (loop mode 21.7 Hz, ζ 0.40): a screw eccentricity of λ 4.219 mm, 11.9 µm, on
    a Benchy layer, whose speeds put v/λ at 4–33 Hz, across the loop. The loop filters and
    lags it unevenly, so a sinusoid of the position at the output fits it nowhere near 4.2 mm
    (its best: 66 mm), and the dynamics form, scanned only ±10 % about the output form's
    best, never saw it: `none`. The dynamics form now ranks the 1–60 mm grid on its own
    (catalogue._periodic_position): named with λ within 1 %, amplitude within 5 %."""
    truth, g, d = _named(dataset("servo606more"), "periodic_position")
    assert g is not None, (truth, d.effects)
    for k, tol in (("wavelength_mm", 0.01), ("amplitude_mm", 0.05)):
        tv = truth["params"][k]
        assert abs(g["params"][k] - tv) <= tol * tv, (k, truth, g)
    assert [(e["kind"], e["axis"]) for e in d.effects] == [("periodic_position", "x")], d.effects


@pytest.mark.slow
def test_an_eccentricity_beside_a_corexys_belt_ring_is_named(dataset):
    """corexy610 (belts 38.9/38.2 Hz, ζ 0.026): on a Benchy layer the belts' ring leaves y
    16.7 µm RMS the draw does not explain (clean log_03), and an 8.3 µm pulley eccentricity
    (λ 6.935 mm) on y explained only 14 % of what the bar left: `none`, though both tests
    passed by far. Relevance is now also taken beyond the mode's ring, the candidate
    beating the ring on both parts too (diagnose._ring_relevance): named with λ within 1 %,
    amplitude within 5 %, and nothing else but the belts' cross-talk."""
    made = dataset("corexy610more")
    truth, g, d = _named(made, "periodic_position")
    assert g is not None, (truth, d.effects)
    for k, tol in (("wavelength_mm", 0.01), ("amplitude_mm", 0.05)):
        tv = truth["params"][k]
        assert abs(g["params"][k] - tv) <= tol * tv, (k, truth, g)
    inherent = {(e["kind"], e["axis"]) for e in made[1]["inherent"]}
    assert {(e["kind"], e["axis"]) for e in d.effects} - inherent == {("periodic_position", "y")}


@pytest.mark.slow
def test_a_friction_the_held_out_part_prefers_is_not_a_backlash(dataset):
    """corexy626 (belts 31.1/30.2 Hz): a Coulomb friction on y (0.0136 mm) on a butterfly.
    A backlash led on the fit part (t 1573 against the friction's 1264), the held-out part
    preferring the friction by far (t 720 against 136): "backlash y 0.0246 mm" was named,
    with a tie. The two exclude each other on an axis, and the held-out part, which neither
    was fitted on, now decides where it prefers one significantly (diagnose._choose)."""
    made = dataset("corexy626more")
    truth, g, d = _named(made, "friction")
    assert g is not None, (truth, d.effects)
    tv = truth["params"]["magnitude_mm"]
    assert abs(g["params"]["magnitude_mm"] - tv) <= 0.15 * tv, (truth, g)
    assert "tie" not in g["params"], g
    assert not [e for e in d.effects if e["kind"] == "backlash"], d.effects


@pytest.mark.slow
def test_the_other_carriages_ring_is_no_fan(dataset):
    """belt23 (x 30.3 Hz, ζ 0.034): y's frame pushed by x's carriage's acceleration (2.32e-6
    mm per mm/s², a rose). The cross-coupling is named, and beside it a 4.2 µm "fan" at 30.8
    Hz was, then (once periodic_time could come twice) a second at 29.0 Hz: x's ring reaches
    y through the frame, its form there a little off the regressor's. A fan near either
    axis's ringing mode must now beat that mode's ring (diagnose._ring_columns): the
    cross-coupling alone, within 12 %."""
    truth, g, d = _named(dataset("belt23more"), "cross_coupling", source="actual")
    assert g is not None, (truth, d.effects)
    tv = truth["params"]["mm_per_mm_s2"]
    assert abs(g["params"]["mm_per_mm_s2"] - tv) <= 0.12 * tv, (truth, g)
    assert [(e["kind"], e["axis"]) for e in d.effects] == [("cross_coupling", "y")], d.effects


@pytest.mark.slow
def test_a_frictions_ring_is_no_fan(dataset):
    """hotend624 (x 23.4 Hz, ζ 0.079): a Coulomb friction on x (0.0253 mm) on a butterfly,
    named, and then a 2.7 µm "fan" at 22.9 Hz beside it (t 40 and 57 against 28 and 6.6):
    the force's step at each reversal rings x's mode, a little off in the twin's form of
    it, and a butterfly's reversals recur lap after lap. The ring a fan must beat is driven
    by the named effects too (diagnose._ring_bar): the friction alone, within 5 %."""
    truth, g, d = _named(dataset("hotend624more"), "friction")
    assert g is not None, (truth, d.effects)
    tv = truth["params"]["magnitude_mm"]
    assert abs(g["params"]["magnitude_mm"] - tv) <= 0.05 * tv, (truth, g)
    assert [(e["kind"], e["axis"]) for e in d.effects] == [("friction", "x")], d.effects


def test_a_column_that_leads_with_the_plant_draw_is_no_friction(dataset):
    """hotend805 (a machine never used before): beside its 16.1 µm fan at 17 Hz on x,
    "friction x 0.00015 mm" was named, form ``force``: a lag of 0.15 µm against the twin's
    mean (the sign the catalogue checked), a lead of 1.55 µm with the plant draw, where the
    test judges it (23 % of the held-out part). A friction lags both ways
    (catalogue._friction): the fan alone, within 0.1 Hz and 5 %."""
    truth, g, d = _named(dataset("hotend805"), "periodic_time")
    assert g is not None, (truth, d.effects)
    assert abs(g["params"]["frequency_hz"] - truth["params"]["frequency_hz"]) < 0.1, g
    tv = truth["params"]["amplitude_mm"]
    assert abs(g["params"]["amplitude_mm"] - tv) <= 0.05 * tv, (truth, g)
    assert [(e["kind"], e["axis"]) for e in d.effects] == [("periodic_time", "x")], d.effects


def test_a_fan_beside_a_mode_is_scanned_on_what_the_draw_leaves(dataset):
    """hotend804 (a machine first run as a check out of sample): a 14.4 µm fan at 34.9 Hz on
    y, 1.3 Hz above y's mode (33.6 Hz, ζ 0.039). Scanned against the twin's mean, the ring of
    the twin's mode (a little off the plant's) pulled it to 34.83 Hz, and 0.07 Hz lost the
    phase over the held-out part: 7.3 of 13.2 µm left with the draw. Scanned on what the draw
    leaves (catalogue._periodic_time): within 0.03 Hz (−0.015), the held-out part with the
    draw under a third of before, the amplitude within 10 % (−7 %: the draw's mode moved
    shares it), nothing else named."""
    truth, g, d = _named(dataset("hotend804"), "periodic_time")
    assert g is not None, (truth, d.effects)
    assert abs(g["params"]["frequency_hz"] - truth["params"]["frequency_hz"]) < 0.03, g
    tv = truth["params"]["amplitude_mm"]
    assert abs(g["params"]["amplitude_mm"] - tv) <= 0.10 * tv, (truth, g)
    ax = truth["axis"]
    h = d.holdout_rms_mm
    assert h["after_with_plant_draw"][ax] < h["before"][ax] / 3, h
    assert [(e["kind"], e["axis"]) for e in d.effects] == [("periodic_time", ax)], d.effects


def _variant(made, kind):
    """(truths, the diagnosis's effects of that kind, Diagnosis) of the data set's log whose
    effects are ``kind`` (machines._variant_effects)."""
    out, labels, prof = made
    e = next(e for e in labels["logs"] if e["effects"][0]["kind"] == kind)
    d = diagnose_log(_log(out, prof, e["file"].split("/")[-1]), prof)
    return e["effects"], [g for g in d.effects if g["kind"] == kind], d


def test_a_fan_switched_on_during_the_log_is_named_with_its_steady_amplitude(dataset):
    """belt700 (x 63.3 Hz, y 54.4 Hz): a fan on the frame switched on 40 % into a rose, as a
    part-cooling fan is after the first layers (benchA's run from t = 0). Fitted as running
    throughout, a fan on for part of the fit part came out at a third of its amplitude, or
    was missed where the dilute sinusoid explained too little held out. Its onset is now
    scanned (catalogue._switched_on): frequency within 0.1 Hz, the steady amplitude within
    5 %, the onset within 20 ms, and nothing else named."""
    truths, got, d = _variant(dataset("belt700variants"), "periodic_time")
    (truth,), (g,) = truths, got
    assert g["axis"] == truth["axis"] and g["form"] == "switched_on", d.effects
    assert abs(g["params"]["frequency_hz"] - truth["params"]["frequency_hz"]) < 0.1, g
    tv = truth["params"]["amplitude_mm"]
    assert abs(g["params"]["amplitude_mm"] - tv) <= 0.05 * tv, (truth, g)
    assert abs(g["params"]["switched_on_s"] - truth["physics"]["onset_s"]) < 0.02, (truth, g)
    assert len(d.effects) == 1, d.effects


@pytest.mark.slow
@pytest.mark.parametrize("which, tol_hz", [("belt712variants", 0.1), ("hotend722variants", 0.12)])
def test_a_fan_switched_on_beside_a_mode_is_named_at_its_frequency(which, tol_hz, dataset):
    """A fan switched on a few Hz below a mode of its axis (belt712: 32.2 Hz, x's mode 36.3 Hz
    ζ 0.075; hotend722: 21.5 Hz, y's 24.4 Hz ζ 0.023): over the part of the fit part the fan
    ran, its spectral peak leans toward the mode's ring by more than the ±2 bins the
    frequency was scanned over. The grid's edge was taken: 712's fan named 0.143 Hz off
    (held out 7.8 → 6.3 µm), 722's missed (the sinusoid 0.34 Hz off lost its phase over the
    held-out part). The scan follows a best at its edge (catalogue._walk) and scores the
    frequency on what the plant draw leaves, which takes out the ring of the twin's mode a
    little off the plant's (against the mean 722's came out +0.144 Hz): named on its axis as
    switched on, 712 within 0.1 Hz (+0.055), 722 within 0.12 Hz (+0.091), the steady
    amplitude within 20 % (+4.2, +16.6 %: the carriage rings in, which the gated sinusoid
    does not model), nothing else named."""
    truths, got, d = _variant(dataset(which), "periodic_time")
    (truth,), (g,) = truths, got
    assert g["axis"] == truth["axis"] and g["form"] == "switched_on", d.effects
    assert abs(g["params"]["frequency_hz"] - truth["params"]["frequency_hz"]) < tol_hz, g
    tv = truth["params"]["amplitude_mm"]
    assert abs(g["params"]["amplitude_mm"] - tv) <= 0.2 * tv, (truth, g)
    assert len(d.effects) == 1, d.effects


def test_two_eccentricities_on_one_axis_are_both_named(dataset):
    """belt700: a belt's tooth pitch and its pulley's runout on one axis (λ 1.5–3 and 20–45
    mm) on a Benchy layer. A kind was named once per axis: the larger was named, the other
    never a candidate. periodic_position may come again apart from those named
    (catalogue.REPEATABLE, _apart): both, λ within 5 % and amplitude within 10 %, nothing
    else."""
    truths, got, d = _variant(dataset("belt700variants"), "periodic_position")
    assert len(got) == 2 and len(d.effects) == 2, d.effects
    for t in truths:
        g = min(got, key=lambda g: abs(1 / g["params"]["wavelength_mm"]
                                       - 1 / t["params"]["wavelength_mm"]))
        assert g["axis"] == t["axis"], (t, g)
        for k, tol in (("wavelength_mm", 0.05), ("amplitude_mm", 0.10)):
            tv = t["params"][k]
            assert abs(g["params"][k] - tv) <= tol * tv, (k, t, g)


@pytest.mark.parametrize("which", ["hotend708variants", "hotend711variants"])
def test_a_friction_that_sticks_the_carriage_is_named_with_its_lag(which, dataset):
    """A Coulomb force of the carriage's own velocity, benchA's form (machines.
    _variant_effects; the other foreign logs' force follows the commanded velocity): the
    carriage sticks at each reversal until the belt's pull exceeds the force. The forms of a
    force of the command sized it 14 % low (hotend708) or left it unnamed (hotend711: 19 % of
    the held-out residual, short of 20 %). Form ``stick`` (catalogue._friction: a play of
    twice the lag on the response): friction on its axis, its lag within 5 %, nothing else."""
    truths, got, d = _variant(dataset(which), "friction")
    (truth,) = truths
    assert [(g["axis"], g["params"]["form"]) for g in got] == [(truth["axis"], "stick")], \
        d.effects
    tv = truth["params"]["magnitude_mm"]
    assert abs(got[0]["params"]["magnitude_mm"] - tv) <= 0.05 * tv, (truth, got)
    assert len(d.effects) == 1, d.effects


@pytest.mark.parametrize("which", ["hotend1", "belt11", "servo43"])
def test_effects_named_with_their_parameter(which, dataset):
    """Three modes (hotend1), and a lightly damped belt (belt11: its −12 % shift must still be
    named where a move inside the members' band no longer is). servo43: its 16 µm fan on y was
    named 0.120 mm while the twin erred 75 µm there (its slow pole out of the lag's reach)."""
    out, labels, prof = dataset(which)
    key = {"delay": "seconds", "gain": "scale", "periodic_time": "amplitude_mm",
           "resonance_shift": "frequency_hz"}
    for e in labels["logs"]:
        truth = e["effects"][0]
        if truth["kind"] == "none":
            continue
        d = diagnose_log(_log(out, prof, e["file"].split("/")[-1]), prof)
        g = next((g for g in d.effects if g["kind"] == truth["kind"] and g["axis"] == truth["axis"]), None)
        assert g is not None, (e["file"], truth, d.effects)
        tv, gv = truth["params"][key[truth["kind"]]], g["params"][key[truth["kind"]]]
        if truth["kind"] == "gain":
            tv, gv = tv - 1, gv - 1
        assert abs(gv - tv) <= 0.05 * abs(tv), (e["file"], truth, g)


def test_a_resonance_shift_comes_without_a_delay_at_the_edge_of_its_scan(dataset):
    """On a servo (seed 25) a −5 % resonance shift on x was named with a 0.196 ms delay on x
    beside it: the delay scan's best point at its lowest end, less delay than the scan tells
    from none (catalogue._delay). Nothing but the shift is named. (The shift itself was
    missed while only one mode could move: six of seven members put the loop mode at ζ
    1.00–1.21, a critically damped loop with no resonance to move; the loaded loop names it,
    17 % low: the pole pair at the peak of a loop damped near critical is ill-defined.)"""
    truth, g, d = _named(dataset("servo25"), "resonance_shift")
    others = [e for e in d.effects if e["kind"] not in ("none", "resonance_shift")]
    assert not others, d.effects


@pytest.mark.parametrize("which, rel", [
    ("servo901", 0.05),
    pytest.param("servo902", 0.05, marks=pytest.mark.slow),
    pytest.param("servo900", None, marks=pytest.mark.slow)])
def test_a_servos_heavier_table_is_named_as_its_loop_loaded(which, rel, dataset):
    """A PID servo's table 1.25–1.4 times heavier moves the whole loop, its poles and damping
    together (ModalModel.loaded). Moving one mode missed 900's and 901's shifts (x 50.3 Hz ζ
    0.74; 15.9 Hz ζ 0.82) and sized 902's (ζ 0.45) +5.9 %; loaded, they are named with
    their held-out RMS more than halved (900: 19.7 → 4.8 µm) and 901's and 902's frequency
    within 5 % (900's 10 % low: its loaded fit puts the peak's pair elsewhere)."""
    truth, g, d = _named(dataset(which), "resonance_shift")
    assert g is not None and g["params"]["form"] == "load", d.effects
    assert [e["kind"] for e in d.effects] == ["resonance_shift"], d.effects
    ax = truth["axis"]
    assert d.holdout_rms_mm["after"][ax] < 0.5 * d.holdout_rms_mm["before"][ax]
    if rel is not None:
        tv = truth["params"]["frequency_hz"]
        assert abs(g["params"]["frequency_hz"] - tv) <= rel * tv, (truth, g)


@pytest.mark.parametrize("which, held_out", [("servo900more", 0.4), ("servo906more", 0.4),
                                              ("servo905more", 0.8)])
def test_a_servos_friction_is_sized_through_the_loop_that_holds_its_table(which, held_out,
                                                                         dataset):
    """900 x (PID loop 50.3 Hz ζ 0.74, table 9.3 kg on a 0.6 kg motor): its table's friction
    was named 70.6 % low in a steady form (response), the held-out part 16.6 → 13.9 µm; through
    the loop, (1 − H)/(s (s + a)) with the corner scanned (ModalModel.load_force), −8.5 % and
    16.6 → 4.3 µm (the label is F × the loop's compliance without its integrator). 906 x and
    905 x, whose twins miss the axis by 14–26 µm: against the mean no washed-out form passed
    (−54, −55 % in a steady form); judged with the plant draw too, −5.3 and +5.0 %, held out
    14.3 → 5.3 and 26.0 → 20.2 µm."""
    truth, g, d = _named(dataset(which), "friction")
    assert g is not None and g["params"]["form"] == "loop", d.effects
    tv = truth["params"]["magnitude_mm"]
    assert abs(g["params"]["magnitude_mm"] - tv) <= 0.1 * tv, (truth, g)
    ax = truth["axis"]
    assert d.holdout_rms_mm["after"][ax] < held_out * d.holdout_rms_mm["before"][ax]


@pytest.mark.parametrize("source, form", [("actual", "loop"), ("command", "loop_command")])
def test_a_servos_table_pushed_by_the_other_axis_is_sized_through_its_loop(source, form,
                                                                           dataset):
    """900 y (PID loop, 10.8 Hz ζ 0.89): x's acceleration pushing y's table was sized 44 and
    48 % low through the command path (forms acceleration, command); through the force path
    of the table its loop holds (forms loop, loop_command), 19 % low, each with its source."""
    truth, g, d = _named(dataset("servo900more"), "cross_coupling", source)
    assert g is not None and g["params"]["form"] == form, d.effects
    tv = truth["params"]["mm_per_mm_s2"]
    assert abs(g["params"]["mm_per_mm_s2"] - tv) <= 0.25 * tv, (truth, g)


def test_a_fan_inside_a_modes_band_is_still_named(dataset):
    """The ring a fan must beat near a mode (diagnose._ring_bar) is driven by the motion; a
    fan at 41 Hz on an axis whose mode is at 41.9 Hz runs on regardless, and is named with
    its amplitude."""
    truth, g, d = _named(dataset("fan23"), "periodic_time")
    assert g is not None, (truth, d.effects)
    assert abs(g["params"]["frequency_hz"] - 41.0) < 0.1, g
    tv = truth["params"]["amplitude_mm"]
    assert abs(g["params"]["amplitude_mm"] - tv) <= 0.05 * tv, (truth, g)


@pytest.mark.slow
def test_a_fan_beside_a_mode_the_twin_places_off_is_named(dataset):
    """belt343, x: the twin's mean leaves the lightly damped mode's ring (34.3 Hz) as the
    largest spectral peak of the residual, the 11.7 µm fan at 24.5 Hz the second. The peak
    whose sinusoid explains most beyond the plant draw is the fan's (catalogue._periodic_time);
    the ring's sinusoid, taken before, was refused by the test and the fan missed. (Slow: its
    own profile build from 7 + 7 FRFs took 23 s of the default run, which it pushed past 16
    minutes.)"""
    _fan_alone_named(dataset("belt343"), amplitude_rel=0.05)


@pytest.mark.slow
def test_a_fan_under_a_slow_miss_of_the_mean_is_named(dataset):
    """servo334fan, x: the twin's mean misses the integral action's 4 Hz doublet by 161 µm RMS
    on the fan's log, the plant draw takes all but 6.6 µm, and the 9.2 µm fan at 30 Hz is most
    of that. The three largest peaks of the mean's residual all lay on the slow miss (the best
    at 2.9 Hz), so the fan's frequency was never scanned and the log read "none"; the peaks of
    what the draw leaves are scanned too now (catalogue._periodic_time). Named at 29.98 Hz,
    8.70 µm (−5.4 %: the twin's mean response at 30 Hz, beside the 32.6 Hz, ζ 0.71 mode); left
    over on x: 1.1 µm beyond the noise, where 6.5 µm was before."""
    d = _fan_alone_named(dataset("servo334fan"), amplitude_rel=0.1)
    assert d.leftover["x"]["excess_mm"] < 0.002, d.leftover["x"]


def test_profile_build_and_diagnose_cli_on_a_servo(dataset, tmp_path):
    """The user's path: `profile build` from the servo's files (its fits have real pole pairs,
    ζ > 1, which the profile schema refused before), then `diagnose` and `predict` with it."""
    import subprocess

    out, _, _ = dataset("servo4")
    prof = tmp_path / "servo.yaml"
    cmd = [sys.executable, "-m", "gcode_feedopt"]
    r = subprocess.run(cmd + ["profile", "build", "--frf-x", *map(str, sorted((out / "frf").glob("x_*.csv"))),
                              "--frf-y", *map(str, sorted((out / "frf").glob("y_*.csv"))), "-o", str(prof)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    r = subprocess.run(cmd + ["diagnose", "-m", str(prof), str(out / "logs" / "log_01.csv"),
                              "--json", "-"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert all(e["kind"] == "none" for e in json.loads(r.stdout)["effects"]), r.stdout
    r = subprocess.run(cmd + ["predict", "-m", str(prof), str(out / "logs" / "log_01.csv"),
                              "-o", str(tmp_path / "p.csv")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("which", ["belt14more", "hotend21more"])
def test_a_dead_band_in_a_belt_drive_is_named_with_its_width(which, dataset):
    """A play between motor and belt, in the foreign physics (machines._play_op on the command
    before the dynamics), named backlash on its axis with its width within 5 % — as on every
    belt machine of seeds 0–23 (7/7, worst +4.2 %; benchmarks/foreign_effects.py). A servo's
    is tested below; a corexy whose twin errs by as much as the play is not tested."""
    truth, g, d = _named(dataset(which), "backlash")
    assert g is not None, (truth, d.effects)
    tv = truth["params"]["magnitude_mm"]
    assert abs(g["params"]["magnitude_mm"] - tv) <= 0.05 * tv, (truth, g)
    assert all(g["kind"] in ("backlash", "none") for g in d.effects), d.effects


@pytest.mark.parametrize("which", ["servo5more", "servo19more"])
def test_a_dead_band_in_a_servo_drive_is_named_with_its_width(which, dataset):
    """A play before a PID servo's loop: its twin's velocity lag is free below the first FRF
    bin, and a lag error τ·v is, on steady motion, the play's b/2·sign(v). Fitted with the
    lag (diagnose._lag_column) the width is within 8 % (seeds 5, 19: +4.9 %, −6.5 %; before,
    +32 %, −38 %: the width took the lag in) and the held-out error drops by half or more."""
    truth, g, d = _named(dataset(which), "backlash")
    assert g is not None, (truth, d.effects)
    tv = truth["params"]["magnitude_mm"]
    assert abs(g["params"]["magnitude_mm"] - tv) <= 0.08 * tv, (truth, g)
    assert "lag_s" in g["params"], g
    ax = truth["axis"]
    assert d.holdout_rms_mm["after"][ax] < 0.5 * d.holdout_rms_mm["before"][ax]
    assert [e["kind"] for e in d.effects] == ["backlash"], d.effects


@pytest.mark.parametrize("which", ["belt14more", "hotend21more"])
def test_a_frame_pushed_by_the_other_axiss_command_is_named(which, dataset):
    """A force on the frame that follows the other axis's *commanded* acceleration
    (machines._more_effects ``cross_coupling_cmd``): named cross_coupling on its axis in form
    ``command`` or ``frame_command`` (through the frame's path), its size within 6 % — on
    every belt machine of seeds 0–23 (7/7, worst +5.0 %; through the command path only and
    sized against the twin's mean, worst +10.6 %; benchmarks/foreign_effects.py). The
    predicted-acceleration regressor alone missed both (its x rings where the command does
    not) and sized the others 25–76 % low."""
    truth, g, d = _named(dataset(which), "cross_coupling", source="command")
    assert g is not None, (truth, d.effects)
    assert g["params"]["form"] in ("command", "frame_command"), g
    assert g["params"]["from_axis"] == truth["params"]["from_axis"]
    tv = truth["params"]["mm_per_mm_s2"]
    assert abs(g["params"]["mm_per_mm_s2"] - tv) <= 0.06 * tv, (truth, g)
    assert all(g["kind"] == "cross_coupling" for g in d.effects), d.effects


@pytest.mark.parametrize("which, source, form", [
    ("hotend802more", "actual", "frame"), ("hotend1more", "command", "frame_command")])
def test_a_frame_force_is_sized_through_the_frames_path(which, source, form, dataset):
    """A belt + hotend machine's frame pushed by the other axis (its carriage's reaction, or
    a force that follows its motor's command): the force reaches the nozzle along the whole
    chain, without the command path's antiresonance (twin.physics.frame_model), and the
    form chosen and weight fitted with the plant draw beside it (catalogue._cross_coupling).
    Named in the frame form, from the right axis, its size within 5 % (−0.3 %, −1.6 %) —
    through the command path, against the twin's mean, it came out +26.0 % (802) and −8.2 %
    (1) (benchmarks/foreign_effects.py)."""
    truth, g, d = _named(dataset(which), "cross_coupling", source=source)
    assert g is not None, (truth, d.effects)
    assert g["params"]["form"] == form, g
    assert g["params"]["from_axis"] == truth["params"]["from_axis"]
    tv = truth["params"]["mm_per_mm_s2"]
    assert abs(g["params"]["mm_per_mm_s2"] - tv) <= 0.05 * tv, (truth, g)
    assert [(e["kind"], e["axis"]) for e in d.effects] == [("cross_coupling", truth["axis"])]


def test_a_coupling_is_chosen_with_the_plant_draw_beside_it(dataset):
    """802 (belt + hotend): x's frame pushed as y's motor is commanded, where the plant draw
    explains half of x's error (18.4 → 9.3 µm held out). Scored against the twin's mean, the
    coupling's best form fitted the mean's miss (form ``belt``, weight ~0) and the test,
    which judges with the draw, refused it: missed. Chosen on what the draw leaves
    (catalogue._cross_coupling): named on x from y, +12 % (its form ``command``, not the
    frame's: its size stays outside 5 %), and the held-out part with the draw 9.3 → 2.7 µm."""
    truth, g, d = _named(dataset("hotend802more"), "cross_coupling", source="command")
    assert g is not None, (truth, d.effects)
    assert g["params"]["from_axis"] == truth["params"]["from_axis"]
    tv = truth["params"]["mm_per_mm_s2"]
    assert abs(g["params"]["mm_per_mm_s2"] - tv) <= 0.15 * tv, (truth, g)
    ax = truth["axis"]
    h = d.holdout_rms_mm
    assert h["after_with_plant_draw"][ax] < 0.5 * h["plant_draw_only"][ax], h
    assert [(e["kind"], e["axis"]) for e in d.effects] == [("cross_coupling", ax)], d.effects


def test_a_servos_friction_is_named_as_its_integrator_sees_it(dataset):
    """A Coulomb friction on a PID servo's table: the loop's integral action takes the steady
    lag out, so the axis is pushed back at each reversal and recovers in ~K_p/K_i. Named
    friction in form ``integral`` (twin.extensions.integral_sign), sized within 15 % of the
    label (the lag of the loop without its integrator, a scale: +11.9 %), and it explains
    most of the held-out error: 21.4 → 4.5 µm, where the steady ``force`` form sized it
    53 % low and left 15.7 µm (benchmarks/foreign_effects.py, seed 8)."""
    truth, g, d = _named(dataset("servo8more"), "friction")
    assert g is not None, (truth, d.effects)
    assert g["params"]["form"] == "integral", g
    tv = truth["params"]["magnitude_mm"]
    assert abs(g["params"]["magnitude_mm"] - tv) <= 0.15 * tv, (truth, g)
    ax = truth["axis"]
    assert d.holdout_rms_mm["after"][ax] < 0.3 * d.holdout_rms_mm["before"][ax]
    assert [e["kind"] for e in d.effects] == ["friction"], d.effects


@pytest.mark.parametrize("which, size_rel", [("servo901more", None), ("servo902more", 0.05)])
def test_a_servos_friction_is_washed_out_where_its_fit_has_no_real_pole(which, size_rel,
                                                                        dataset):
    """A Coulomb friction on a PID servo whose modal fit shows no real pole (its integrator
    below the FRF band, or two heavily damped pairs in its place): the friction is tried
    washed out by the integrator on every axis now (catalogue._friction), named in form
    ``integral`` and explains most of the held-out error — 901: 13.7 → 4.9 µm (a steady form,
    sized 77 % low, left 12.9), 902: 4.7 → 2.2 µm and its size within 5 % (−0.2 %; the
    steady form: −77.7 %, 4.2 µm). 901's size is +82 %: the label is a scale there, the lag
    of the loop without its integrator (benchmarks/foreign_effects.py marks it ``*``). Since
    the force through the loop (form ``loop``) is tried too, 902's takes it: −2.9 %, 1.9 µm
    held out."""
    truth, g, d = _named(dataset(which), "friction")
    assert g is not None, (truth, d.effects)
    assert g["params"]["form"] in ("integral", "loop"), g
    ax = truth["axis"]
    assert d.holdout_rms_mm["after"][ax] < 0.5 * d.holdout_rms_mm["before"][ax], d.holdout_rms_mm
    if size_rel is not None:
        tv = truth["params"]["magnitude_mm"]
        assert abs(g["params"]["magnitude_mm"] - tv) <= size_rel * tv, (truth, g)
    assert [e["kind"] for e in d.effects] == ["friction"], d.effects


@pytest.mark.parametrize("which, kind, source, form", [
    ("belt14more", "cross_coupling", "command", "frame_command"),
    ("hotend802more", "cross_coupling", "actual", "frame"),
    ("servo8more", "friction", None, "integral"),
    ("servo5more", "backlash", None, "input"),
    ("hotend708variants", "friction", None, "stick"),
    ("servo901", "resonance_shift", None, "load"),
    ("servo900more", "friction", None, "loop"),
    ("servo905more", "cross_coupling", "command", "loop_command")])
def test_a_written_extension_predicts_what_diagnose_reported(which, kind, source, form,
                                                             dataset, tmp_path):
    """Issue 19, point 4, for the ``frame_command`` and ``frame`` forms of a cross-coupling, the
    ``integral`` form of a servo's friction, a servo's backlash with its twin's lag error,
    a friction that sticks, a servo's heavier table and its friction through the loop: the profile ``diagnose -o`` writes, loaded back and run by
    ``predict --no-learn``, has the held-out RMS ``diagnose`` reported, within 10 % (each
    term is computed in predict as in diagnose: from the other axis's command, through the
    frame response; through the force response, washed out in the fitted ``integral_s``; the
    lag −``lag_s``·v̂ of the twin's own prediction; the play of twice the lag on it), and a
    servo's loaded loop (a ``resonance_shift`` of form ``load``: the written ratio and
    corner load every member's fit, ``twin.physics.apply_effects``) and a friction through
    it (form ``loop``: the force response at the written corner, ``AxisPhysics.load_force``),
    as is a coupling on that table (form ``loop_command``)."""
    from gcode_feedopt.profile.io import save_profile

    from ..written_extension import diagnose_then_predict

    out, labels, prof = dataset(which)
    e = next(e for e in labels["logs"] if e["effects"][0]["kind"] == kind
             and source in (None, e["effects"][0]["physics"].get("source")))
    log = out / "logs" / e["file"].split("/")[-1]
    base = save_profile(prof, tmp_path / "base.yaml")
    d, got = diagnose_then_predict(base, log, tmp_path)
    named = [(g["kind"], g["params"]["form"]) for g in d["effects"]]
    assert named == [(kind, form)], named
    ax = e["effects"][0]["axis"]
    rms = got[ax]
    want = d["holdout_rms_mm"]["after"][ax]
    assert abs(rms - want) <= 0.1 * want, (rms, want)
    # a servo's coupling is small beside what its twin's mean misses (905 y: 4.8 → 3.3 µm)
    most = 0.75 if which == "servo905more" else 0.5
    assert want < most * d["holdout_rms_mm"]["before"][ax]


def test_two_eccentricities_written_predict_what_diagnose_reported(dataset, tmp_path):
    """Issue 19, point 4, for two effects of one kind on one axis (belt700's tooth pitch and
    pulley runout): the profile ``diagnose -o`` writes carries both, and ``predict
    --no-learn`` with it has the held-out RMS ``diagnose`` reported, within 10 %."""
    from gcode_feedopt.profile.io import save_profile

    from ..written_extension import diagnose_then_predict

    out, labels, prof = dataset("belt700variants")
    e = next(e for e in labels["logs"] if e["effects"][0]["kind"] == "periodic_position")
    ax = e["effects"][0]["axis"]
    base = save_profile(prof, tmp_path / "base.yaml")
    d, got = diagnose_then_predict(base, out / "logs" / e["file"].split("/")[-1], tmp_path)
    assert [(g["kind"], g["axis"]) for g in d["effects"]] == [("periodic_position", ax)] * 2
    kinds = [x["kind"] for x in load_profile(tmp_path / "ext.yaml").axes[ax].effects]
    assert kinds == ["periodic_position"] * 2, kinds
    want = d["holdout_rms_mm"]["after"][ax]
    assert abs(got[ax] - want) <= 0.1 * want, (got[ax], want)
    assert want < 0.5 * d["holdout_rms_mm"]["before"][ax]


@pytest.mark.slow
@pytest.mark.parametrize("which", ["hotend1once", "servo4once"])
def test_a_machine_measured_once_is_covered_by_a_typical_spread(which, dataset):
    """One FRF per axis has no spread; a twin that took it for the machine's covered these
    machines' clean logs 89.1 % (hotend1) and 17.9 % (servo4) at worst by its 95 % interval.
    A typical machine's spread stands in (twin.modal._with_prior_spread): ≥ 93 % on every clean
    log and axis without learning (98.4 % and 99.6 % measured)."""
    out, labels, prof = dataset(which)
    for e in labels["logs"]:
        log = _log(out, prof, e["file"].split("/")[-1])
        for i, ax in enumerate("xy"):
            mean, std = axis_twin(prof, ax).run(log.cmd_mm[:, i], log.pos_mm[:, i], learn=False)
            w = log.warmup
            inside = float(np.mean(np.abs(log.pos_mm[w:, i] - mean[w:]) <= 1.96 * std[w:]))
            assert inside > 0.93, (which, e["file"], ax, inside)


@pytest.mark.slow
def test_a_machine_measured_once_names_nothing_on_a_clean_log(dataset):
    """corexy3 measured once: its log_03 was named "resonance_shift y 56.4 Hz", a move no
    spread of one member could hold (AxisPhysics.move_inside_spread had nothing to compare
    with). A typical machine's spread holds it; the belts' cross-talk is inherent."""
    out, labels, prof = dataset("corexy3once")
    inherent = {(e["kind"], e["axis"]) for e in labels["inherent"]}
    d = diagnose_log(_log(out, prof, "log_03.csv"), prof)
    named = [g for g in d.effects if g["kind"] != "none" and (g["kind"], g["axis"]) not in inherent]
    assert not named, named
