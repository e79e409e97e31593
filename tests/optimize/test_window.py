"""The window problem (optimize/window.py) against closed forms and brute force."""

from __future__ import annotations

import numpy as np
import pytest

from gcode_feedopt.optimize import window as win
from gcode_feedopt.optimize.mpc import LP_ACC_MARGIN, MpcPlanner, MpcSettings
from gcode_feedopt.optimize.predictors import FirPredictor

from .synthetic import Circle, Line, fir_response, second_order_impulse

TS = 0.002


def _planner(geom, h, *, tol=0.1, z=0.0, vmax=70.0, amax=3000.0, solver="highs", **kw):
    p = MpcPlanner(geom, FirPredictor(h, h), ts_s=TS, vmax_mm_s=vmax, amax_mm_s2=amax,
                   tol_mm=tol, z=z, settings=MpcSettings(solver=solver, **kw))
    p.start(0.0)
    return p


@pytest.mark.parametrize("order", [1, 2, 3])
def test_diff_rows_match_brute_force(order):
    rng = np.random.default_rng(1)
    n = 12
    tan = rng.normal(size=n)
    ds = rng.uniform(0, 1, n)
    s_start = 3.0
    past = rng.normal(size=order)
    s = s_start + np.cumsum(ds)
    x = np.concatenate([past, tan * s])
    direct = np.diff(x, order)  # (n,)
    DL, past_w = win._diff_rows(tan, order)
    # the s_start part is carried by the constant term in build_lp; check the Δs part
    x0 = np.concatenate([past, tan * s_start])
    const = np.diff(x0, order)
    np.testing.assert_allclose(DL @ ds + const, direct, atol=1e-12)
    # and the history weights alone reproduce the differences of the past-only part
    xp = np.concatenate([past, np.zeros(n)])
    np.testing.assert_allclose(past_w @ past, np.diff(xp, order), atol=1e-12)


def test_line_from_rest_follows_the_acceleration_limit_exactly():
    """No dynamics (h = δ), X line: s_k = A Ts² (k+1)(k+2)/2 until V_max (closed form of the
    discrete double integrator at the limit), then V_max, and the horizon ends at rest."""
    geom = Line([1, 0, 0], 200.0)
    p = _planner(geom, np.array([1.0]), n_window=30)
    s_ref = np.full(p.n, 0.0)
    w = p._window_data(0.0, s_ref, 200.0, trust=50.0)
    sol = win.solve_window(w)
    assert sol.status == win.STATUS_OPTIMAL
    k = np.arange(p.n)
    a_ts2 = 3000.0 * LP_ACC_MARGIN * TS ** 2
    expect = a_ts2 * (k + 1) * (k + 2) / 2
    ramp = np.cumsum(np.minimum(np.diff(np.concatenate([[0.0], expect])), 70.0 * TS))
    m = 8  # well before the speed cap (k+1)·A·Ts = 70 mm/s at k ≈ 11
    np.testing.assert_allclose(sol.s_mm[:m], ramp[:m], rtol=1e-7, atol=1e-9)
    ds = np.diff(np.concatenate([[0.0], sol.s_mm]))
    assert ds.max() <= 70.0 * TS * (1 + 1e-9)
    assert np.all(ds[-p.st.n_hold:] <= 1e-12)  # held at rest at the end of the horizon
    acc = np.abs(np.diff(np.concatenate([[0.0, 0.0], sol.s_mm]), 2)) / TS ** 2
    assert acc.max() <= 3000.0 * (1 + 1e-7)


def test_solution_satisfies_every_row_and_the_linearised_chance_constraint(mode40):
    geom = Circle(8.0)
    p = _planner(geom, mode40, tol=0.05, z=1.645)
    p.run_piece(10.0)
    s0 = p.s_hist[-1]
    s_bar = np.full(p.n, s0)
    w = p._window_data(s0, s_bar, geom.total_length_mm, trust=1.0)
    w = win.WindowData(**{**w.__dict__, "sigma_mm": np.full(p.n, 0.005)})
    lp = win.build_lp(w)
    sol = win.solve_window(w)
    assert sol.status == win.STATUS_OPTIMAL
    x = sol.ds_mm / lp.ds_ref_mm
    assert win.violation(lp, x) < 1e-7
    mu, sig = win.predicted_contour(w, sol.ds_mm)
    assert np.all(np.abs(mu) + 1.645 * sig <= 0.05 + 1e-7)
    assert sol.s_mm[-1] > s0  # it moves


def test_mpc_circle_keeps_true_contour_error_within_tolerance(mode40):
    """Known plant (z = 0): the executed contour error of the committed plan stays within
    E_max up to the verification slack, accelerations and feed within their limits, and the
    plan ends at rest exactly at the end of the path."""
    geom = Circle(10.0)
    tol = 0.03
    p = _planner(geom, mode40, tol=tol)
    p.run_piece(geom.total_length_mm)
    p.hold(150)  # let the residual vibration ring out
    s = p.result().s_mm
    assert s[-1] == pytest.approx(geom.total_length_mm, abs=1e-12)
    assert np.all(np.diff(s) >= -1e-12)
    cmd = geom.position(s)[:, :2]
    act = fir_response(cmd, mode40)
    err = np.abs(np.hypot(act[:, 0], act[:, 1]) - 10.0)
    assert err.max() <= tol * 1.03
    assert np.diff(s).max() / TS <= 70.0 * (1 + 1e-9)
    acc = np.abs(np.diff(cmd, 2, axis=0)).max() / TS ** 2
    assert acc <= 3000.0 * 1.011
    assert np.diff(s)[-150:].max() <= 1e-12


def test_tighter_tolerance_gives_longer_cycle(mode40):
    geom = Circle(3.0)  # centripetal 1.6 m/s² at 70 mm/s: the tolerance binds below ~0.03 mm
    times = []
    for tol in (0.05, 0.02, 0.01):
        p = _planner(geom, mode40, tol=tol)
        p.run_piece(geom.total_length_mm)
        times.append(p.result().s_mm.size * TS)
    assert times[0] < times[1] < times[2]


def test_osqp_agrees_with_highs_on_a_window(mode40):
    geom = Circle(10.0)
    p = _planner(geom, mode40, tol=0.05)
    p.run_piece(5.0)
    s0 = p.s_hist[-1]
    w = p._window_data(s0, np.full(p.n, s0), geom.total_length_mm, trust=0.5)
    a = win.solve_window(w, solver="highs")
    b = win.solve_window(w, solver="osqp")
    assert a.status == win.STATUS_OPTIMAL
    if b.status == win.STATUS_OPTIMAL:
        lp = win.build_lp(w)
        oa = lp.c @ (a.ds_mm / lp.ds_ref_mm)
        ob = lp.c @ (b.ds_mm / lp.ds_ref_mm)
        assert ob == pytest.approx(oa, rel=1e-3)
    else:
        assert b.status == win.STATUS_FAILED  # never a silent wrong answer


def test_osqp_update_keeps_the_pattern(mode40):
    """Two windows of the same shape: the second is an in-place update (explicit zeros kept),
    not a new setup."""
    geom = Line([1, 0, 0], 100.0)  # tangent Y = 0 exactly: zeros that must stay structural
    p = _planner(geom, mode40, tol=0.05)
    w = p._window_data(0.0, np.zeros(p.n), 100.0, trust=1.0)
    slv = win.OsqpWindowSolver()
    win.solve_window(w, solver="osqp", osqp_solver=slv)
    first = slv._prob
    w2 = win.WindowData(**{**w.__dict__, "tol_mm": 0.04})
    win.solve_window(w2, solver="osqp", osqp_solver=slv)
    assert slv._prob is first


def test_no_solver_banner_on_stdout():
    """HiGHS prints "Running HiGHS ..." on the process's stdout when constructed; stdout is
    the user's (tables, `-o -`): nothing of it may appear there."""
    import subprocess
    import sys

    code = ("from gcode_feedopt.optimize import window; "
            "assert window._highs() is not None; print('done')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, check=True)
    assert out.stdout == b"done\n"
