"""Closed forms of the extension terms ``twin.extensions`` adds to the prediction."""

from __future__ import annotations

import math

import numpy as np

from gcode_feedopt.twin.extensions import PARAMS, additive_term, integral_sign

TS = 0.002


def _ramp_and_hold(n_move=300, n_hold=400, v_mm_s=20.0):
    """A command that moves at v for n_move samples, then holds."""
    x = np.concatenate([np.arange(n_move) * v_mm_s * TS, np.full(n_hold, n_move * v_mm_s * TS)])
    return np.concatenate([np.zeros(50), x])


def test_integral_sign_is_the_force_step_washed_out_exponentially():
    """−sign(v) through τs/(1 + τs): after the motion starts the step decays as a^(k+1),
    a = e^{−Ts/τ} (the discrete filter's pole: exp(−t/τ) at the samples), moving or not; at
    the stop the opposite step leaves the low-passed part, decaying the same way."""
    from gcode_feedopt.vm.effects import velocity_sign

    cmd = _ramp_and_hold()
    tau = 0.04
    s = integral_sign(cmd, TS, tau)
    a = math.exp(-TS / tau)
    moving = np.flatnonzero(velocity_sign(cmd, TS))
    start, stop = int(moving[0]), int(moving[-1]) + 1
    k = np.arange(0, stop - start)
    assert np.all(s[:start] == 0.0)
    assert np.allclose(s[start + k], -a ** (k + 1), rtol=1e-12, atol=1e-15)
    low = -(1.0 - a ** (stop - start))           # what the low-pass held at the stop
    k = np.arange(0, cmd.size - stop)
    assert np.allclose(s[stop + k], -low * a ** (k + 1), rtol=1e-9, atol=1e-15)


def test_a_long_integral_time_is_the_steady_force_form():
    """τ → ∞: nothing is washed out, the ``integral`` form is the ``force`` form."""
    cmd = _ramp_and_hold()
    h = np.exp(-np.arange(40) / 6.0)
    h /= h.sum()
    p = {"magnitude_mm": 0.02}
    steady = additive_term("friction", {**p, "form": "force"}, cmd, TS, h, path_h=h)
    washed = additive_term("friction", {**p, "form": "integral", "integral_s": 1e4}, cmd, TS, h,
                           path_h=h)
    assert np.max(np.abs(washed - steady)) < 1e-5 * 0.02 * 10
    short = additive_term("friction", {**p, "form": "integral", "integral_s": 0.02}, cmd, TS, h,
                          path_h=h)
    # a short integral time: the lag is gone by the end of the move
    end = 50 + 299
    assert abs(short[end]) < 1e-3 * abs(steady[end])
    assert "integral" in PARAMS["friction"]["form"]


def test_a_friction_that_sticks_lags_a_move_and_holds_through_the_reversal():
    """Form ``stick`` (a force of the carriage's own velocity): a steady move trails the
    prediction by the magnitude, and after a reversal the axis stands still until the
    prediction has come back 2·magnitude, then trails it by the magnitude the other way."""
    m = 0.02
    up = np.arange(200) * 20.0 * TS                      # 0 → 7.96 mm at 20 mm/s
    down = up[-1] - np.arange(1, 200) * 20.0 * TS        # and back
    cmd = np.concatenate([np.zeros(20), up, down])
    h = np.zeros(10)
    h[0] = 1.0                                           # the prediction is the command
    off = additive_term("friction", {"magnitude_mm": m, "form": "stick"}, cmd, TS, h)
    assert np.allclose(off[:20], 0.0, atol=1e-12)        # starts centred, at rest
    assert np.allclose(off[20 + 50:220], -m)             # trailing on the way up
    stuck = cmd + off
    top = stuck[219]
    back = 220 + np.flatnonzero(cmd[220:] < cmd[219] - 2 * m)
    assert np.allclose(stuck[220:back[0]], top)          # holds while the pull reverses
    assert np.allclose(off[back[5]:], m)                 # then trails the other way
    assert "stick" in PARAMS["friction"]["form"]


def test_a_friction_through_the_loop_is_its_force_response_at_the_magnitude():
    """Form ``loop``: −sign(v_cmd) (no relaxation) through the load's force response
    (``AxisPhysics.load_force``, passed as path_h), times the magnitude."""
    from gcode_feedopt.twin.extensions import relax_sign
    from gcode_feedopt.vm.plant import respond

    cmd = _ramp_and_hold()
    h = np.exp(-np.arange(40) / 6.0)
    h /= h.sum()
    hf = np.diff(np.exp(-np.arange(41) / 9.0))            # a washed-out force response
    p = {"magnitude_mm": 0.02, "form": "loop", "corner_hz": 30.0}
    got = additive_term("friction", p, cmd, TS, h, path_h=hf)
    np.testing.assert_allclose(got, 0.02 * respond(relax_sign(cmd, TS, 0.0), hf), atol=1e-15)
    assert "loop" in PARAMS["friction"]["form"] and "corner_hz" in PARAMS["friction"]


def test_a_coupling_through_the_loop_is_the_other_axiss_acceleration_through_its_path():
    """Forms ``loop`` (the other axis's predicted position) and ``loop_command`` (its
    command): their acceleration through the path's response (path_h) times the weight."""
    from gcode_feedopt.vm.plant import respond

    cmd = _ramp_and_hold()
    other_cmd = 0.5 * cmd[::-1].copy()
    other_pred = other_cmd + 0.01 * np.sin(np.arange(cmd.size) / 7.0)
    h = np.exp(-np.arange(40) / 6.0)
    h /= h.sum()
    hf = np.diff(np.exp(-np.arange(41) / 9.0))

    def acc(p):
        return np.gradient(np.gradient(p, TS), TS)

    for form, src in (("loop", other_pred), ("loop_command", other_cmd)):
        p = {"from_axis": "x", "mm_per_mm_s2": 3e-6, "corner_hz": 40.0, "form": form}
        got = additive_term("cross_coupling", p, cmd, TS, h, other_pred_mm=other_pred,
                            other_cmd_mm=other_cmd, path_h=hf)
        np.testing.assert_allclose(got, 3e-6 * respond(acc(src), hf), atol=1e-15)
