"""The foreign-machine generator against closed forms: its time simulation agrees with its own
FRF (steady-state sine), a position axis at rest sits at its command, a delay is a shift, and the
labels are what the physics did. The twin and diagnosis tests on these machines are in
test_twin_foreign.py; the generator must be right first."""

from __future__ import annotations

import json

import numpy as np
import pytest

from .machines import KINDS, R, _fine, _sim_fine, axis_frf, make_machine, respond_xy, write_dataset

TS = 0.002


def _sine_gain(ch, f0, delay_steps=0):
    """Complex steady-state ratio of the simulated response to a sampled sine (the firmware's
    command is linear between samples: its fundamental is the sine's × sinc²(f·Ts))."""
    t = np.arange(4000) * TS
    u = 0.1 * np.sin(2 * np.pi * f0 * t)
    y = _sim_fine(ch, _fine(u, delay_steps), TS, None)
    tt = t[-1500:]
    A = np.column_stack([np.sin(2 * np.pi * f0 * tt), np.cos(2 * np.pi * f0 * tt)])
    c = np.linalg.lstsq(A, y[-1500:], rcond=None)[0]
    hold = np.sinc(f0 * TS) ** 2
    return (c[0] + 1j * c[1]) / 0.1 / hold


@pytest.mark.parametrize("kind", KINDS)
def test_simulation_agrees_with_the_frf(kind):
    mach = make_machine(11, kind)
    for ch in mach.chans.values():
        for f0 in (7.0, 31.0, 83.0):
            got = _sine_gain(ch, f0)
            want = ch.frf([f0])[0]
            assert abs(got - want) < 2e-3 * max(1.0, abs(want)), (kind, f0, got, want)


@pytest.mark.parametrize("kind", KINDS)
def test_dc_gain_one_and_rest_at_command(kind):
    mach = make_machine(12, kind)
    for ch in mach.chans.values():
        assert abs(ch.frf([1e-4])[0] - 1) < 1e-6
    # a move and a long rest: every kind settles on the command
    x = np.concatenate([np.linspace(10, 60, 200), np.full(800, 60.0)])
    y = np.concatenate([np.linspace(20, 0, 200), np.full(800, 0.0)])
    mach.sensor_noise_mm = 0.0
    mach.sensor_q_mm = 1e-9
    xs, ys = respond_xy(mach, mach.chans, x, y, TS)
    assert abs(xs[0] - 10) < 1e-9 and abs(ys[0] - 20) < 1e-9
    assert abs(xs[-1] - 60) < 1e-4 and abs(ys[-1]) < 1e-4


def test_delay_is_a_shift_and_in_the_frf():
    mach = make_machine(3, "belt_frame")
    ch = mach.chans["x"]
    f0, d = 23.0, 10  # fine steps: 1 ms
    got = _sine_gain(ch, f0, d)
    want = ch.frf([f0])[0] * np.exp(-2j * np.pi * f0 * d * TS / R)
    assert abs(got - want) < 2e-3 * abs(want)
    assert np.allclose(axis_frf(mach.chans, "x", [f0], d * TS / R), want)


def test_corexy_axes_cross_talk_only_through_the_mismatch():
    mach = make_machine(0, "corexy")
    mach.sensor_noise_mm, mach.sensor_q_mm = 0.0, 1e-9
    t = np.arange(1500)
    x = 50 + 20 * np.sin(2 * np.pi * t * TS * 3) * (t > 100)
    y = np.full(t.size, 30.0)
    xs, ys = respond_xy(mach, mach.chans, x, y, TS)
    assert np.ptp(ys) > 1e-4                       # y moves with x's command...
    same = dict(mach.chans, b=mach.chans["a"])     # ...and not when the belts match
    xs2, ys2 = respond_xy(mach, same, x, y, TS)
    assert np.ptp(ys2) < 1e-9


def test_dataset_layout_and_labels(tmp_path):
    mach = make_machine(1, "belt_hotend")
    labels = write_dataset(mach, tmp_path)
    assert labels == json.loads((tmp_path / "labels.json").read_text())
    assert len(list((tmp_path / "frf").glob("x_*.csv"))) == mach.n_meas
    head = (tmp_path / "logs" / "log_01.csv").read_text().splitlines()[0]
    assert head == "t,x_cmd,y_cmd,x,y"
    kinds = [e["effects"][0]["kind"] for e in labels["logs"]]
    assert kinds == ["none", "none", "none", "delay", "periodic_time", "gain", "resonance_shift"]
    f = np.loadtxt(tmp_path / "frf" / "x_1.csv", delimiter=",", skiprows=1)
    start, stop, step = mach.frf_grid
    assert f[0, 0] == start and f[-1, 0] <= stop and np.allclose(np.diff(f[:, 0]), step)


def _quiet(seed, kind):
    mach = make_machine(seed, kind)
    mach.sensor_noise_mm, mach.sensor_q_mm = 0.0, 1e-9
    return mach


@pytest.mark.parametrize("kind", ["belt_frame", "belt_hotend"])
def test_drive_effects_do_what_their_labels_say(kind):
    """The drive's effects (write_dataset's ``more_effects``) at quasi-static conditions: a
    dead band lags a move by half its width, an eccentric pulley offsets a rest by
    A sin(2π u/λ + φ), a Coulomb friction lags a steady move by F × the carriage compliance
    (benchA's quasi-static lag; of the carriage's own velocity it also holds the carriage
    inside that band at rest), a frame force of coef × the other axis's acceleration
    displaces this axis by coef × the frame compliance per mm/s²."""
    mach = _quiet(3, kind)
    ch = mach.chans["x"]
    t = np.arange(3000) * TS
    ramp = 10 + np.clip(20 * (t - 0.2), 0, 50)        # 20 mm/s for 2.5 s, then rest at 60
    y = np.full(t.size, 5.0)
    x0, _ = respond_xy(mach, mach.chans, ramp, y, TS)
    xb, _ = respond_xy(mach, mach.chans, ramp, y, TS, play={"x": 0.04})
    assert abs(x0[-1] - xb[-1] - 0.02) < 1e-5
    xe, _ = respond_xy(mach, mach.chans, ramp, y, TS, ecc={"x": (0.01, 4.0, 0.3)})
    assert abs(xe[-1] - x0[-1] - 0.01 * np.sin(2 * np.pi * 60 / 4.0 + 0.3)) < 1e-5
    F = 0.03 / ch.compliance("carriage")
    xf, _ = respond_xy(mach, mach.chans, ramp, y, TS, friction={"x": F})
    i = int(2.6 / TS)                                  # steady motion, 2.4 s into the ramp
    assert abs(x0[i] - xf[i] - 0.03) < 3e-4
    # the same force of the carriage's own velocity (benchA's): the same steady lag; once
    # the command stops, the carriage rings without it and with the force of the command's
    # velocity, and sticks with this one (then creeps in over ~magnitude / V_FRICTION_ACTUAL)
    xs, _ = respond_xy(mach, mach.chans, ramp, y, TS, friction={"x": (F, "actual")})
    assert abs(x0[i] - xs[i] - 0.03) < 3e-4
    after = slice(int((2.7 + 0.02) / TS), int((2.7 + 0.06) / TS))
    assert np.ptp(xs[after]) < 0.1 * min(np.ptp(x0[after]), np.ptp(xf[after]))
    # y accelerates at a constant 500 mm/s²: x's frame is pushed by a steady force
    ya = 5 + 250 * np.clip(t - 0.2, 0, None) ** 2
    c = 4e-6
    xc0, _ = respond_xy(mach, mach.chans, np.full(t.size, 10.0), ya, TS)
    xc, _ = respond_xy(mach, mach.chans, np.full(t.size, 10.0), ya, TS,
                       frame_force={"x": (c / ch.compliance("frame"), "y", "command")})
    i = int(2.6 / TS)
    assert abs(xc[i] - xc0[i] - c * 500) < 1e-4


def test_more_effects_leave_every_other_file_as_it_was(tmp_path):
    import hashlib

    mach = make_machine(6)
    a, b = tmp_path / "a", tmp_path / "b"
    write_dataset(mach, a)
    labels = write_dataset(mach, b, more_effects=True)
    for f in a.rglob("*.csv"):
        assert hashlib.sha256(f.read_bytes()).digest() == \
            hashlib.sha256((b / f.relative_to(a)).read_bytes()).digest(), f
    old = json.loads((a / "labels.json").read_text())
    assert labels["logs"][:len(old["logs"])] == old["logs"]
    kinds = [e["effects"][0]["kind"] for e in labels["logs"][len(old["logs"]):]]
    assert kinds == ["backlash", "periodic_position", "friction", "cross_coupling",
                     "cross_coupling"]
