"""Done-when of the twin: on logs simulated from plants drawn from the profile's own FRF
distribution, the 95 % predictive interval holds 93–97 % of the positions, both axes.

Pooled over plant draws: one draw is one machine, and its errors are correlated over the whole
run, so a single draw's coverage is either near 100 % or far below 95 % — only the population
is calibrated. The measured position carries σ_ε noise, which the interval includes."""

import numpy as np
import pytest
from scipy.signal import oaconvolve

from gcode_feedopt.gcode.path import build_path
from gcode_feedopt.gcode.reader import read_file
from gcode_feedopt.plan.kinematic import plan_kinematic
from gcode_feedopt.profile import load_profile
from gcode_feedopt.twin.frf import draw_impulse_responses
from gcode_feedopt.twin.model import axis_twin

from ..conftest import REPO

Z95 = 1.959964


@pytest.fixture(scope="module")
def butterfly():
    prof = load_profile("ender3pro")
    prog = read_file(REPO / "sample_gcode" / "butterfly.gcode")
    path = build_path(prog)
    sched = plan_kinematic(path, prof)
    return prof, path.position(sched.s_mm)


def simulate(prof, axis, x_cmd, h, rng):
    x_true = x_cmd[0] + oaconvolve(x_cmd - x_cmd[0], h)[:x_cmd.size]
    return x_true + prof.twin.sigma_eps_mm * rng.standard_normal(x_cmd.size)


@pytest.mark.parametrize("axis", ["x", "y"])
def test_95_interval_coverage_without_learning(butterfly, axis):
    prof, pos = butterfly
    x_cmd = pos[:, "xy".index(axis)]
    rng = np.random.default_rng(11)
    H = draw_impulse_responses(prof.axes[axis].frf, prof.ts_s, prof.twin.n_taps, rng, 400,
                               method=prof.twin.coef_variance)
    tw = axis_twin(prof, axis)
    tw.cov[:] = 0.0  # weights fixed at the physics prior: only the known uncertainty
    mean, std = tw.run(x_cmd, None, learn=False)
    inside = [np.abs(simulate(prof, axis, x_cmd, h, rng) - mean) <= Z95 * std for h in H]
    frac = np.mean(inside)
    assert 0.93 <= frac <= 0.97, frac


@pytest.mark.parametrize("axis", ["x", "y"])
def test_95_interval_coverage_with_learning(butterfly, axis):
    """Learning online (one sample behind) from the measured log: the twin learns which
    machine of the population this is (the plant draw as a latent variable, jointly with the
    regression weights), so its interval narrows to the noise and stays calibrated."""
    prof, pos = butterfly
    x_cmd = pos[:, "xy".index(axis)]
    rng = np.random.default_rng(21)
    H = draw_impulse_responses(prof.axes[axis].frf, prof.ts_s, prof.twin.n_taps, rng, 12,
                               method=prof.twin.coef_variance)
    inside, widths = [], []
    for h in H:
        x_meas = simulate(prof, axis, x_cmd, h, rng)
        tw = axis_twin(prof, axis)
        mean, std = tw.run(x_cmd, x_meas, learn=True)
        inside.append(np.abs(x_meas - mean) <= Z95 * std)
        widths.append(np.median(std[-1000:]))
    frac = np.mean(inside)
    assert 0.93 <= frac <= 0.97, frac
    # and it has learned: the late interval is the sensor noise, not the population's spread
    assert np.median(widths) < 1.5 * prof.twin.sigma_eps_mm
