"""Twin predictor against the twin's reference run, the ensemble impulse response against
Monte Carlo, the shift-invariant prior, and the methods end to end on the virtual machine."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from gcode_feedopt.optimize.methods import make_twin_predictor, plan_schedule, shift_invariant_cov
from gcode_feedopt.profile import load_profile
from gcode_feedopt.twin.frf import draw_impulse_responses, ensemble_impulse_response, \
    impulse_response
from gcode_feedopt.twin.model import axis_twin

from ..conftest import REPO


@pytest.fixture(scope="module")
def ender():
    return load_profile("ender3pro")


def _trajectory(ts, T=600):
    t = np.arange(T) * ts
    return np.column_stack([10 + 20 * np.sin(2 * np.pi * 3 * t) * np.minimum(4 * t, 1),
                            5 + 8 * np.cos(2 * np.pi * 5 * t)])


def test_twin_predictor_equals_the_twin_run_window_by_window(ender):
    """Committing a trajectory 30 samples at a time gives the same mean and std as
    twin.model.AxisTwin.run over the whole of it (closed-form horizon recursion with error
    feedback weights, full feature covariance)."""
    rng = np.random.default_rng(0)
    cmd = _trajectory(ender.ts_s)
    pr = make_twin_predictor(ender, "pidd", learn=False)
    for a in range(2):
        pr.mu[a][2 + ender.twin.n2:] = rng.normal(0, 0.02, ender.twin.n3)
        pr._rec.clear()
    for k in range(0, cmd.shape[0], 30):
        pr.commit(k, cmd[k:k + 30])
    for a, ax in enumerate("xy"):
        tw = axis_twin(ender, ax, method="pidd")
        tw.mu, tw.cov = pr.mu[a].copy(), pr.cov[a].copy()
        mean, std = tw.run(cmd[:, a], None, learn=False)
        np.testing.assert_allclose(pr.pred_mean[a], mean, atol=1e-10)
        np.testing.assert_allclose(pr.pred_std[a], std, rtol=1e-9)


def test_twin_predictor_jacobian_is_the_derivative(ender):
    cmd = _trajectory(ender.ts_s, 200)
    pr = make_twin_predictor(ender, "pidd", learn=False)
    pr.commit(0, cmd[:100])
    h = cmd[100:164]
    mean, jac, _ = pr.predict(100, h)
    d = np.zeros_like(h)
    d[10, 0] = 1e-3
    mean2, _, _ = pr.predict(100, h + d)
    np.testing.assert_allclose((mean2[0] - mean[0]) / 1e-3, jac[0][:, 10], atol=1e-8)


def test_ensemble_impulse_response_is_the_sample_statistics_of_the_measured_responses(ender):
    frf = ender.axes["x"].frf
    ir = ensemble_impulse_response(frf.freq_hz, frf.response, ender.ts_s, 500)
    own = np.vstack([ensemble_impulse_response(frf.freq_hz, frf.response[i:i + 1], ender.ts_s,
                                               500).mean for i in range(frf.response.shape[0])])
    np.testing.assert_allclose(ir.mean, own.mean(0), atol=1e-12)
    np.testing.assert_allclose(ir.factor @ ir.factor.T, np.cov(own.T), atol=1e-12)
    # draws: Monte Carlo covariance, and the DC gain every measured FRF shares stays certain
    H = draw_impulse_responses(frf, ender.ts_s, 500, np.random.default_rng(1), 20000,
                               method="ensemble")
    assert np.allclose(np.var(H, axis=0), ir.var, rtol=0.05, atol=1e-12)
    assert np.std(H.sum(axis=1)) < 1e-6
    # and it is far tighter than the per-bin (paper Eq. 9) scatter on a printing move
    from gcode_feedopt.twin.features import xhat

    t = np.arange(3000) * ender.ts_s
    x = np.cumsum(np.where((t % 1.0) < 0.5, 50.0, -50.0) * ender.ts_s)
    v_ens = xhat(ir, x)[1].max()
    v_bin = xhat(impulse_response(frf, ender.ts_s, 500, method="minmax"), x)[1].max()
    assert v_ens < v_bin / 4


def test_shift_invariant_prior_does_not_grow_with_distance_from_the_start(ender):
    from gcode_feedopt.twin.features import physics_prior

    n2, n3 = ender.twin.n2, ender.twin.n3
    mu, cov = physics_prior(n2, n3)
    cs = shift_invariant_cov(cov, n2)
    psi = np.concatenate([[0.0], np.linspace(0, 0.5, n2 + 1), np.zeros(n3)])  # x̂ block only
    shifted = psi.copy()
    shifted[1:2 + n2] += 177.0
    assert shifted @ cov @ shifted > 100 * (psi @ cov @ psi)  # the plain prior does grow
    # shift-invariant: only the (tiny) DC-gain variance sees the translation
    assert abs(shifted @ cs @ shifted - psi @ cs @ psi) < 2 * (177.0 * (n2 + 1)) ** 2 * 1e-12
    assert np.linalg.eigvalsh(cs).min() >= -1e-18


@pytest.fixture(scope="module")
def butterfly_piece(ender):
    import pathlib

    from gcode_feedopt.pipeline import path_for, read_for

    lines = (REPO / "sample_gcode" / "butterfly.gcode").read_bytes().splitlines(keepends=True)
    p = pathlib.Path(__import__("tempfile").mkdtemp()) / "piece.gcode"
    p.write_bytes(b"".join(lines[:300]))
    return p, path_for(read_for(p, ender), ender)


def test_pidd_online_on_the_virtual_machine_keeps_tolerance_and_beats_conservative(ender):
    """The whole butterfly with an unknown 0.05 mm sinusoid (issue 5's setting, reduced)."""
    from gcode_feedopt.optimize.compare import run_compare
    from gcode_feedopt.pipeline import path_for, read_for
    from gcode_feedopt.vm.effects import parse_effect
    from gcode_feedopt.vm.plant import Plant

    path = path_for(read_for(REPO / "sample_gcode" / "butterfly.gcode", ender), ender)
    plant = Plant(ender, seed=0, effects=[parse_effect("sinusoid:axis=x,amp_mm=0.05")],
                  nominal=True)
    runs = {r.method: r for r in run_compare(path, ender, plant,
                                             methods=("conservative", "pidd", "oracle"),
                                             tolerance_mm=0.1, stringency=0.95)}
    pidd, cons, orc = runs["pidd"], runs["conservative"], runs["oracle"]
    assert pidd.within_fraction >= 0.95
    assert pidd.rms_gamma_um <= cons.rms_gamma_um + 1e-9
    assert pidd.cycle_time_s <= 1.10 * orc.cycle_time_s
    assert pidd.cycle_time_s <= cons.cycle_time_s
    # the schedule is a valid progression along the whole path
    assert pidd.info["relaxed_windows"] == 0


def test_higher_stringency_is_slower(ender, butterfly_piece):
    _, path = butterfly_piece
    times = [plan_schedule("pidd", path, ender, tolerance_mm=0.04, stringency=eta).duration_s
             for eta in (0.6, 0.99)]
    assert times[1] > times[0]


def test_schedule_is_monotone_and_respects_axis_acceleration(ender, butterfly_piece):
    _, path = butterfly_piece
    s = plan_schedule("pb", path, ender, tolerance_mm=0.1, stringency=0.95)
    assert s.s_mm[0] == 0.0 and abs(s.s_mm[-1] - path.s0_mm[-1]) < 1e-6
    assert np.all(np.diff(s.s_mm) >= -1e-12)
    xy = path.position(s.s_mm)[:, :2]
    acc = np.abs(np.diff(xy, 2, axis=0)) / s.ts_s ** 2
    assert acc.max() <= 1.02 * 3000.0


def test_optimize_cli_pidd_end_to_end_reports_plan_vs_executed(tmp_path, butterfly_piece):
    src, _ = butterfly_piece
    before = src.read_bytes()
    out = tmp_path / "out.gcode"
    rep = tmp_path / "r.json"
    r = subprocess.run([sys.executable, "-m", "gcode_feedopt", str(src), "-o", str(out),
                        "--machine", "ender3pro", "--method", "pidd", "--report", str(rep)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert src.read_bytes() == before
    d = json.loads(rep.read_text())
    ex = d["extra"]["executed"] if "extra" in d else d["executed"]
    assert abs(ex["time_s"] - d["plan_time_s"]) <= 0.02 * d["plan_time_s"]
    assert ex["within_fraction"] >= 0.95
    assert d["predicted_max_contour_error_mm"] is not None


def test_compare_cli_prints_table_and_writes_json_and_png(tmp_path, butterfly_piece):
    src, _ = butterfly_piece
    js, png = tmp_path / "c.json", tmp_path / "c.png"
    r = subprocess.run([sys.executable, "-m", "gcode_feedopt", "compare", str(src), "-m",
                        "ender3pro", "--methods", "kinematic,pb", "--json", str(js),
                        "--plot", str(png)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "RMS γ" in r.stdout and "pb" in r.stdout
    rows = json.loads(js.read_text())["rows"]
    assert [x["method"] for x in rows] == ["kinematic", "pb"]
    assert png.stat().st_size > 10000
    bad = subprocess.run([sys.executable, "-m", "gcode_feedopt", "compare", str(src), "-m",
                          "ender3pro", "--methods", "fast"], capture_output=True, text=True)
    assert bad.returncode == 2 and "unknown fast" in bad.stderr


def test_tolerance_below_the_twin_noise_floor_is_refused_with_the_fix(ender, butterfly_piece):
    from gcode_feedopt.errors import FeedOptError

    _, path = butterfly_piece
    with pytest.raises(FeedOptError, match="--tolerance above"):
        plan_schedule("pidd", path, ender, tolerance_mm=0.01, stringency=0.95)
