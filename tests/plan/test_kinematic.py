"""Kinematic planner against closed forms."""

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from gcode_feedopt.gcode.path import build_path
from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.plan.kinematic import plan_kinematic
from gcode_feedopt.plan.trapezoid import forward_backward, junction_speeds, sample, trapezoids
from gcode_feedopt.profile import load_profile

PROF = load_profile("ender3pro")  # V 70 mm/s, A 3000 mm/s², JD 0.013 mm


def plan_text(text, **kw):
    prog = read_program(text.encode(), "t")
    path = build_path(prog)
    return path, plan_kinematic(path, PROF, **kw)


def test_triangle_profile_time():
    # 10 mm along X from rest to rest: v_peak = sqrt(a L) = 173 > 70 -> trapezoid
    path, s = plan_text("G1 X0 Y0 F600\nG1 X10 Y0 F600\n")
    a, v, L = 3000.0, 70.0, 10.0
    t_exact = L / v + v / a
    assert s.info["plan_time_s"] == pytest.approx(t_exact, rel=1e-12)
    # 1 mm: triangle, t = 2 sqrt(L/a)
    path, s = plan_text("G1 X0 Y0 F600\nG1 X1 Y0 F600\n")
    assert s.info["plan_time_s"] == pytest.approx(2 * math.sqrt(1 / 3000.0), rel=1e-12)


def test_diagonal_axis_limited_acceleration():
    # at 45°, each axis sees a·cos45: the path may accelerate at 3000/cos45 but the feed cap
    # V=70 still holds; with a 1 mm triangle the time is 2 sqrt(L/(a√2))
    path, s = plan_text(f"G1 X0 Y0 F600\nG1 X{1 / math.sqrt(2):.12f} Y{1 / math.sqrt(2):.12f}\n")
    assert s.info["plan_time_s"] == pytest.approx(2 * math.sqrt(1 / (3000 * math.sqrt(2))), rel=1e-9)


def test_sampling_matches_closed_form():
    path, s = plan_text("G1 X0 Y0 F600\nG1 X10 Y0 F600\n")
    t = np.arange(s.n_samples) * s.ts_s
    a, v = 3000.0, 70.0
    ta = v / a
    T = s.info["plan_time_s"]
    exp = np.where(t < ta, 0.5 * a * t ** 2,
                   np.where(t < T - ta, 0.5 * a * ta ** 2 + v * (t - ta),
                            10 - 0.5 * a * np.clip(T - t, 0, None) ** 2))
    np.testing.assert_allclose(s.s_mm, np.clip(exp, 0, 10), atol=1e-9)


def test_junction_speed_90_degrees_junction_deviation():
    # 90° corner: sin(θ/2) = sin 45°; v² = a δ s/(1-s)
    v = junction_speeds(np.array([0.0]), np.array([3000.0, 3000.0]), 0.013,
                        np.array([70.0, 70.0]), np.array([False, True]))
    sd = math.sin(math.pi / 4)
    assert v[1] == pytest.approx(math.sqrt(3000 * 0.013 * sd / (1 - sd)), rel=1e-12)
    assert v[0] == 0 and v[2] == 0


def test_reversal_and_stops_are_exact_stops():
    v = junction_speeds(np.array([-1.0, 1.0]), np.full(3, 3000.0), 0.013, np.full(3, 70.0),
                        np.array([False, True, True]))
    assert v[1] == 0.0 and v[2] == 0.0
    # straight on: no junction limit, only the caps
    v = junction_speeds(np.array([1.0]), np.full(2, 3000.0), 0.013, np.full(2, 70.0),
                        np.array([False, True]))
    assert v[1] == 70.0


def test_forward_backward_reachability():
    vj = forward_backward(np.array([0, 1e9, 1e9, 0.0]), np.array([1.0, 1.0, 1.0]),
                          np.array([1000.0, 1000.0, 1000.0]))
    assert vj[1] == pytest.approx(math.sqrt(2 * 1000 * 1.0))
    assert vj[2] == pytest.approx(math.sqrt(2 * 1000 * 1.0))


def test_arc_centripetal_limit():
    path, s = plan_text("G1 X1 Y0 F600\nG3 X-1 Y0 I-1 J0 F6000\nG3 X1 Y0 I1 J0\n")
    v = s.speed_mm_s()
    on_arc = path.kind[path.segment_at(s.s_mm)] != 0
    on_arc[1:] &= on_arc[:-1]  # the speed of interval k ends at sample k: both ends on arcs
    # v²/R ≤ A, the firmware's limit on the chords of an arc (Marlin's small-segment rule)
    assert v[on_arc].max() <= math.sqrt(3000 * 1) * 1.001
    assert v[on_arc].max() >= math.sqrt(3000 * 1) * 0.95  # and it is used


def test_use_slicer_feed_caps_speed():
    path, s = plan_text("G1 X0 Y0 F600\nG1 X100 Y0 F1200\n", use_slicer_feed=True)
    assert s.speed_mm_s().max() <= 20.0 + 1e-6


@settings(max_examples=30, deadline=None)
@given(st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=2, max_size=20))
def test_axis_limits_hold_on_random_polylines(pts):
    assume(any(math.hypot(x, y) > 1e-3 for x, y in pts))
    text = "G1 X0 Y0 F6000\n" + "".join(f"G1 X{x:.3f} Y{y:.3f} E{k + 1}\n" for k, (x, y) in enumerate(pts))
    path, s = plan_text(text)
    pos = path.position(s.s_mm)
    v = np.diff(pos, axis=0) / s.ts_s
    speed = np.linalg.norm(v[:, :2], axis=1)
    assert speed.max() <= 70 * (1 + 1e-9) + 1e-9
    assert np.all(np.diff(s.s_mm) >= 0)
    assert s.s_mm[-1] == pytest.approx(path.total_length_mm)
    # away from junction instants the per-axis acceleration is within the limit
    seg = path.segment_at(s.s_mm)
    acc = np.diff(pos, n=2, axis=0) / s.ts_s ** 2
    same = (seg[:-2] == seg[2:])
    assert np.all(np.abs(acc[same, :2]) <= 3000 * 1.001 + 1e-6)


def test_trapezoid_sample_ends_at_total():
    tr = trapezoids(np.array([0.0, 0.0]), np.array([5.0]), np.array([1000.0]), np.array([50.0]),
                    np.array([0.1]))
    s = sample(tr, np.array([0.0, 5.0]), 0.002)
    assert s[-1] == 5.0 and (len(s) - 1) * 0.002 >= tr.duration_s - 1e-12


def test_marlin_small_segments_are_arcs():
    """Marlin 2's JD_HANDLE_SMALL_SEGMENTS: a circle drawn with 0.05 mm chords is taken at the
    arc's centripetal speed √(a·R), not at the (much higher) per-junction deviation speed;
    long segments and sharp turns keep the junction-deviation rule."""
    from gcode_feedopt.plan.trapezoid import small_segment_limits

    R, L, a = 1.0, 0.05, 3000.0
    theta = L / R
    cos = np.full(4, math.cos(theta))
    v = small_segment_limits(cos, np.full(5, a), np.full(5, L))
    np.testing.assert_allclose(v, math.sqrt(a * R), rtol=1e-12)
    # collinear short blocks: Marlin's acos polynomial bottoms out at 0.033 rad
    v0 = small_segment_limits(np.ones(4), np.full(5, a), np.full(5, 0.03))
    np.testing.assert_allclose(v0, math.sqrt(0.03 * a / 0.0329), rtol=1e-12)
    # 2 mm segments, or a 60° turn: no small-segment limit
    assert np.all(np.isinf(small_segment_limits(cos, np.full(5, a), np.full(5, 2.0))))
    assert np.all(np.isinf(small_segment_limits(np.full(4, 0.5), np.full(5, a), np.full(5, L))))
