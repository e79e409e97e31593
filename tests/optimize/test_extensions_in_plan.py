"""The optimizer plans with the profile's extensions that move with the motion (issue 19): a
cross-coupling that ``diagnose -o`` wrote is part of the mean the chance bound is judged on,
through the slow-down's windows exactly as over the whole file."""

from __future__ import annotations

import numpy as np
import pytest

from gcode_feedopt import pipeline
from gcode_feedopt.closedloop.extend import extend_profile
from gcode_feedopt.optimize.methods import make_twin_predictor, plan_schedule
from gcode_feedopt.optimize.predictors import predict_trajectory
from gcode_feedopt.profile import load_profile
from gcode_feedopt.twin.extensions import motion_offsets

from ..conftest import REPO
from .test_end_to_end import with_limits

BUTTERFLY = REPO / "sample_gcode" / "butterfly.gcode"
#: a corexy's belt cross-talk, y from x: ~25 µm at 5 m/s² (tests/foreign: 64–96 % of a drawn
#: corexy's cross-talk is this form)
BELT = {"kind": "cross_coupling", "axis": "y",
        "params": {"from_axis": "x", "mm_per_mm_s2": 5e-6, "form": "belt"}}


def _setup():
    prof = with_limits(load_profile("ender3pro"), 150.0, 5000.0)
    path = pipeline.path_for(pipeline.read_for(BUTTERFLY, prof), prof)
    return prof, extend_profile(prof, [BELT]), path


def test_only_motion_kinds_reach_the_plan():
    prof, ext, _ = _setup()
    assert motion_offsets(prof) is None
    fan = {"kind": "periodic_time", "axis": "x", "params": {"frequency_hz": 20.0,
                                                            "amplitude_mm": 0.01}}
    assert motion_offsets(extend_profile(prof, [fan])) is None
    off, memory = motion_offsets(ext)
    n = max(np.asarray(make_twin_predictor(prof, "pidd", learn=False).h[0]).size, 1)
    assert memory >= 2 * n  # belt: through the dynamics twice


def test_the_plan_is_judged_with_the_cross_coupling():
    """The prediction of the final plan (assembled from the slow-down's windows and checked
    with the whole memory) is the twin's whole-file mean plus the extension's term, to 1 nm;
    the term is tens of µm, so the plan slows down more than without it."""
    prof, ext, path = _setup()
    tol, eta = 0.05, 0.95
    plain = plan_schedule("pidd", path, prof, tolerance_mm=tol, stringency=eta)
    sch = plan_schedule("pidd", path, ext, tolerance_mm=tol, stringency=eta)
    s = sch.s_mm
    cmd = path.position(s)[:, :2]
    off, _ = motion_offsets(ext)
    term = off(cmd)
    assert np.abs(term[:, 1]).max() > 0.01 and np.abs(term[:, 0]).max() == 0.0
    tp = make_twin_predictor(ext, "pidd", learn=False)
    mean, _ = predict_trajectory(tp, cmd, ref=cmd[0])
    np.testing.assert_allclose(sch.info["_predicted_xy_mm"], mean.T + term, atol=1e-6)
    assert sch.duration_s > plain.duration_s
    assert sch.info["relaxed_samples"] == 0


def test_a_command_form_coupling_follows_the_other_axiss_command():
    """Form ``command``: the other axis's *commanded* acceleration through this axis's
    dynamics (a motor force that follows the command), not its predicted motion: the term
    moves with x's command, equals the closed form on any command, and ``predict``'s mean
    (mean_offsets) and the plan's (motion_offsets) agree."""
    from gcode_feedopt.twin.extensions import additive_term, mean_offsets
    from gcode_feedopt.twin.physics import axis_impulse
    from gcode_feedopt.vm.plant import respond

    prof, _, path = _setup()
    cmd_e = {"kind": "cross_coupling", "axis": "y",
             "params": {"from_axis": "x", "mm_per_mm_s2": 4e-6, "form": "command"}}
    ext = extend_profile(prof, [cmd_e])
    sch = plan_schedule("kinematic", path, prof, tolerance_mm=0.1, stringency=0.95)
    cmd = path.position(sch.s_mm)[:, :2]
    ts = prof.ts_s
    hy = np.asarray(axis_impulse(prof, "y").mean)
    hy = hy / hy.sum()
    acc_x = np.gradient(np.gradient(cmd[:, 0], ts), ts)
    want = 4e-6 * respond(acc_x, hy)
    off, _ = motion_offsets(ext)
    np.testing.assert_allclose(off(cmd)[:, 1], want, atol=1e-12)
    np.testing.assert_allclose(mean_offsets(ext, cmd)[:, 1], want, atol=1e-12)
    assert np.abs(want).max() > 1e-3 and np.abs(off(cmd)[:, 0]).max() == 0.0
    # the predicted-acceleration form differs: x's ringing is in it, not in the command's
    pred_x = respond(cmd[:, 0], np.asarray(axis_impulse(prof, "x").mean) /
                     np.sum(axis_impulse(prof, "x").mean))
    acc = additive_term("cross_coupling", {**cmd_e["params"], "form": "acceleration"},
                        cmd[:, 1], ts, hy, other_pred_mm=pred_x, other_cmd_mm=cmd[:, 0])
    assert np.abs(acc - want).max() > 0.1 * np.abs(want).max()


@pytest.mark.parametrize("forms, extra", [(("frame", "frame_command"), {}),
                                           (("loop", "loop_command"), {"corner_hz": 60.0})])
def test_a_coupling_of_its_own_path_goes_through_that_paths_response(forms, extra):
    """Forms ``frame`` / ``frame_command``: the other axis's predicted / commanded
    acceleration through this axis's response to a force on its frame
    (twin.physics.frame_model; ender3pro's fit has the antiresonance it takes out); forms
    ``loop`` / ``loop_command`` (a servo's table pushed by the other axis): through the force
    response of the load the axis's loop holds at the written corner (AxisPhysics.load_force).
    The closed form, the same in ``predict``'s mean (mean_offsets) and the plan's
    (motion_offsets), and not the command path's term."""
    from gcode_feedopt.twin.extensions import mean_offsets
    from gcode_feedopt.twin.physics import axis_impulse, axis_physics
    from gcode_feedopt.vm.plant import respond

    prof, _, path = _setup()
    sch = plan_schedule("kinematic", path, prof, tolerance_mm=0.1, stringency=0.95)
    cmd = path.position(sch.s_mm)[:, :2]
    ts = prof.ts_s
    phys = axis_physics(prof)["y"]
    path_y = phys.frame if forms[0] == "frame" else phys.load_force(2 * np.pi * 60.0)
    assert path_y is not None
    hx, hy = (np.asarray(axis_impulse(prof, a).mean) for a in "xy")
    hx, hy = hx / hx.sum(), hy / hy.sum()

    def acc(p):
        return np.gradient(np.gradient(p, ts), ts)

    for form, src in zip(forms, (respond(cmd[:, 0], hx), cmd[:, 0])):
        e = {"kind": "cross_coupling", "axis": "y",
             "params": {"from_axis": "x", "mm_per_mm_s2": 4e-6, "form": form, **extra}}
        ext = extend_profile(prof, [e])
        want = 4e-6 * respond(acc(src), path_y)
        off, _ = motion_offsets(ext)
        np.testing.assert_allclose(off(cmd)[:, 1], want, atol=1e-12)
        np.testing.assert_allclose(mean_offsets(ext, cmd)[:, 1], want, atol=1e-12)
        assert np.abs(off(cmd)[:, 0]).max() == 0.0
        through_cmd = 4e-6 * respond(acc(src), hy)
        assert np.abs(through_cmd - want).max() > 0.05 * np.abs(want).max()
