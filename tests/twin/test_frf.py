"""Known uncertainty: impulse-response mean/variance against Monte Carlo."""

import numpy as np
import pytest

from gcode_feedopt.profile import load_profile
from gcode_feedopt.profile.builtin import frf_campaign
from gcode_feedopt.profile.schema import Mode
from gcode_feedopt.twin.features import xhat
from gcode_feedopt.twin.frf import (coefficient_stats, draw_coefficients, draw_impulse_responses,
                                    impulse_response, paper_eq11_variance)

TS = 0.002


def synthetic_frfs(seed=1):
    frf, _ = frf_campaign([Mode(40.0, 0.1, 0.6), Mode(55.0, 0.08, 0.4)], seed)
    return frf


@pytest.mark.parametrize("method", ["minmax", "sample"])
def test_tap_variance_matches_monte_carlo(method):
    frf = synthetic_frfs()
    n = 400
    ir = impulse_response(frf, TS, n, method=method)
    rng = np.random.default_rng(7)
    draws = np.vstack([draw_impulse_responses(frf, TS, n, rng, 10000, method=method)
                       for _ in range(10)])  # 10^5 draws: MC std error of a variance ~0.45 %
    mc_mean = draws.mean(0)
    mc_var = draws.var(0)
    energy = ir.mean ** 2 / np.sum(ir.mean ** 2)
    big = energy >= 0.01
    assert big.sum() >= 5
    np.testing.assert_allclose(mc_var[big], ir.var[big], rtol=0.03)
    np.testing.assert_allclose(mc_mean, ir.mean, atol=5 * np.sqrt(ir.var.max() / draws.shape[0]))
    # and the full covariance of a few taps
    idx = np.flatnonzero(big)[:4]
    mc_cov = np.cov(draws[:, idx].T)
    np.testing.assert_allclose(mc_cov, ir.cov[np.ix_(idx, idx)], rtol=0.05,
                               atol=0.05 * ir.var[idx].max())


def test_paper_eq11_is_not_the_variance():
    frf = synthetic_frfs()
    st = coefficient_stats(frf.freq_hz, frf.response, TS)
    ir = impulse_response(frf, TS, 300)
    eq11 = paper_eq11_variance(st, 300)
    # Eq. 11 mixes σ_a² − σ_b² and can even be negative; ours is a variance
    assert np.any(eq11 < 0) or np.max(np.abs(eq11 - ir.var)) > 0.1 * ir.var.max()
    assert np.all(ir.var >= 0)


def test_covariance_changes_the_position_variance():
    """A long move then standstill: the DC gain is certain (all FRFs are 1 at 0 Hz), so the
    position at rest is certain. The diagonal-only formula (paper Eq. 12) says it is not."""
    frf = synthetic_frfs()
    ir = impulse_response(frf, TS, 500)
    t = np.arange(3000) * TS
    x = np.where(t < 1.0, 50 * np.clip(t, 0, 1), 50.0)  # ramp 50 mm/s for 1 s, then rest
    _, v_full = xhat(ir, x)
    _, v_diag = xhat(ir, x, diagonal_only=True)
    rest = t > 2.5
    assert np.sqrt(v_full[rest]).max() < 1e-3  # µm-level: the machine has settled
    assert np.sqrt(v_diag[rest]).min() > 10 * np.sqrt(v_full[rest]).max()
    # Monte Carlo of the position variance agrees with the full-covariance formula
    rng = np.random.default_rng(3)
    H = draw_impulse_responses(frf, TS, 500, rng, 4000)
    from scipy.signal import oaconvolve
    xs = oaconvolve(H, (x - x[0])[None, :], axes=1)[:, :x.size]
    k = np.argmax(v_full)
    assert xs[:, k].var() == pytest.approx(v_full[k], rel=0.08)


def test_builtin_profile_gives_physical_impulse_response():
    prof = load_profile("ender3pro")
    ir = impulse_response(prof.axes["y"].frf, prof.ts_s, prof.twin.n_taps)
    assert ir.mean.sum() == pytest.approx(1.0, abs=2e-3)  # unit DC gain
    rng = np.random.default_rng(0)
    spec = draw_coefficients(coefficient_stats(prof.axes["y"].frf.freq_hz,
                                               prof.axes["y"].frf.response, TS), rng, 3)
    assert spec.shape[1] == 501


def test_more_taps_than_the_grid_determines_are_refused_on_every_route():
    """A 2 Hz grid at Ts 2 ms determines N = 250 taps; beyond them the inverse DFT repeats
    itself, and a member's 500-tap response trailed its command by ~0.5 s (tests/foreign
    seed 15 with `twin.physics: bins`). Every raw-bin constructor names the limit."""
    from gcode_feedopt.twin.frf import member_impulses

    f = np.arange(1.0, 150.0, 2.0)
    resp = np.array([1.0 / (1 + 2j * np.pi * f * 0.002 + (1j * f / 40.0) ** 2)] * 3)
    rng = np.random.default_rng(0)
    for call in (lambda: member_impulses(f, resp, TS, 500),
                 lambda: impulse_response(f, resp, TS, 500, method="ensemble"),
                 lambda: impulse_response(f, resp, TS, 500),
                 lambda: draw_impulse_responses(f, resp, TS, 500, rng, 2)):
        with pytest.raises(ValueError, match="n_taps 500 exceeds the estimable length N_h = 250"):
            call()
    assert member_impulses(f, resp, TS, 250).shape == (3, 250)
