"""Metrics against hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest

from gcode_feedopt.vm import metrics as m
from gcode_feedopt.vm.trajectory import Trajectory

TS = 0.002


def square(side_mm=10.0, speed_mm_s=20.0):
    """Closed square centred at 0, counter-clockwise from (h, -h), sampled at speed."""
    h = side_mm / 2
    corners = np.array([[h, -h], [h, h], [-h, h], [-h, -h], [h, -h]])
    step = speed_mm_s * TS
    pts = [corners[0]]
    for a, b in zip(corners[:-1], corners[1:]):
        n = int(round(np.linalg.norm(b - a) / step))
        pts.extend(a + (b - a) * (np.arange(1, n + 1) / n)[:, None])
    xy = np.array(pts)
    return np.column_stack([xy, np.full(len(xy), 0.2)])


def traj(pos, e=None):
    return Trajectory(ts_s=TS, pos_mm=pos, e_mm=np.zeros(len(pos)) if e is None else e)


def test_scaled_square_has_the_closed_form_error():
    cmd = square()
    s = 1.01
    act = cmd.copy()
    act[:, :2] *= s
    eps = m.contour_error_mm(cmd, act, TS)
    # a point (s*5, s*p) on the right edge: 0.05 from the edge when |s p| <= 5, else from the corner
    h = 5.0
    ax, ay = np.abs(act[:, 0]), np.abs(act[:, 1])
    # by symmetry: distance to the square of half-side h from a point outside it
    expect = np.hypot(np.maximum(ax - h, 0), np.maximum(ay - h, 0))
    np.testing.assert_allclose(eps, expect, atol=1e-12)
    assert eps.max() == pytest.approx(0.05 * np.sqrt(2), abs=1e-12)


def test_gamma_rms_within_fraction_hand_case():
    eps = np.array([0.05, 0.1, -0.2, 0.08])
    np.testing.assert_allclose(m.tolerance_violation_mm(eps, 0.08), [0, 0.02, 0.12, 0])
    cmd = np.column_stack([np.linspace(0, 4, 5) * 0 + np.arange(5.0), np.zeros(5), np.zeros(5)])
    act = cmd.copy()
    act[:, 1] = [0.0, 0.05, 0.1, 0.2, 0.0]
    res = m.evaluate(traj(cmd), act, 0.08, on="xy")
    assert res.rms_gamma_mm == pytest.approx(np.sqrt((0.02**2 + 0.12**2) / 5))
    assert res.max_gamma_mm == pytest.approx(0.12)
    assert res.within_fraction == pytest.approx(3 / 5)
    assert res.max_contour_error_mm == pytest.approx(0.2)
    # 95th percentile of (0, 0, 0.05, 0.1, 0.2) by linear interpolation: 0.1 + 0.8 * 0.1
    assert res.p95_contour_error_mm == pytest.approx(0.18)
    assert res.cycle_time_s == pytest.approx(4 * TS)
    d = res.to_dict()
    for key in ("cycle_time_s", "rms_gamma_mm", "within_fraction", "max_contour_error_mm"):
        assert key in d


def test_error_is_measured_against_the_line_being_drawn_not_its_neighbour():
    """Two parallel lines 0.4 mm apart drawn 0.5 s apart; actual 0.3 mm off toward the second
    while drawing the first: error 0.3 (the nearest point of the whole path is 0.1 away)."""
    n = 250
    x = np.linspace(0, 10, n)
    first = np.column_stack([x, np.zeros(n), np.zeros(n)])
    second = np.column_stack([x[::-1], np.full(n, 0.4), np.zeros(n)])
    cmd = np.vstack([first, second])
    act = cmd.copy()
    act[:n, 1] += 0.3
    eps = m.contour_error_mm(cmd, act, TS)
    np.testing.assert_allclose(eps[20:n - 40], 0.3, atol=1e-12)
    np.testing.assert_allclose(eps[n + 40:], 0.0, atol=1e-12)


def test_extrusion_mask_skips_travel_and_retraction():
    # travel 0..9, retract (E down, XY still) 10..12, extrude 13..22, hold 23..25
    x = np.concatenate([np.linspace(0, 9, 10), np.full(3, 9.0), np.linspace(9.5, 14, 10), np.full(3, 14.0)])
    e = np.concatenate([np.zeros(10), [-0.5, -1.0, -1.0], -1.0 + 0.05 * np.arange(1, 11), np.full(3, -0.5)])
    pos = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    mask = m.extrusion_mask(traj(pos, e))
    expect = np.zeros(x.size, bool)
    expect[12:23] = True  # sample 12 starts the first extruding interval
    np.testing.assert_array_equal(mask, expect)
    res = m.evaluate(traj(pos, e), pos, 0.1)
    assert res.n_evaluated == 11 and res.evaluated_on == "extrusion"


def test_travel_stopping_as_a_prime_starts_is_not_extrusion():
    # a travel decelerates and stops within interval 9→10, in which an E-only prime also
    # starts; then the extrusion 13..22. Both XY and E advance over 9→10, but neither end of it
    # lies in an extruding move: the moves tell it apart (the firmware model's blocks)
    x = np.concatenate([np.linspace(0, 8.999, 10), np.full(3, 9.0), np.linspace(9.5, 14, 10)])
    e = np.concatenate([np.zeros(10), [0.2, 0.4, 0.5], 0.5 + 0.05 * np.arange(1, 11)])
    pos = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    blk = np.zeros(x.size, bool)
    blk[13:] = True  # samples inside the extruding move
    plain = m.extrusion_mask(traj(pos, e))
    assert plain[9] and plain[10]  # XY and E alone call the stop an extrusion
    told = m.extrusion_mask(Trajectory(ts_s=TS, pos_mm=pos, e_mm=e, in_extrusion=blk))
    expect = np.zeros(x.size, bool)
    expect[12:] = True
    np.testing.assert_array_equal(told, expect)


def test_no_extrusion_falls_back_to_all_samples():
    cmd = square()
    res = m.evaluate(traj(cmd), cmd, 0.1)
    assert res.evaluated_on == "xy" and res.n_evaluated == len(cmd)
    assert res.max_contour_error_mm < 1e-15 and res.within_fraction == 1.0


def test_prediction_rms_per_axis():
    cmd = square()
    pred = cmd.copy()
    pred[:, 0] += 0.03
    pred[::2, 1] += 0.04  # half the samples
    res = m.evaluate(traj(cmd), cmd, 0.1, predicted_mm=pred)
    assert res.prediction_rms_mm["x"] == pytest.approx(0.03)
    assert res.prediction_rms_mm["y"] == pytest.approx(0.04 * np.sqrt(np.ceil(len(cmd) / 2) / len(cmd)))


def test_windowed_distance_matches_brute_force():
    rng = np.random.default_rng(7)
    poly = np.cumsum(rng.normal(size=(400, 2)), axis=0)
    pts = poly + rng.normal(scale=0.3, size=poly.shape)
    W = 400  # the whole polyline: compare with an all-segments brute force
    got = m.distance_to_polyline_window(pts, poly, W)
    a, b = poly[:-1], poly[1:]
    d = b - a
    r = pts[:, None, :] - a[None]
    u = np.clip(np.einsum("mkj,kj->mk", r, d) / np.einsum("kj,kj->k", d, d), 0, 1)
    brute = np.linalg.norm(r - u[..., None] * d[None], axis=2).min(axis=1)
    np.testing.assert_allclose(got, brute, atol=1e-12)


def test_standing_still_the_window_keeps_the_path_around_the_command():
    """A command that runs along X, stops for 0.4 s and goes on: the machine overshooting
    0.08 mm *along* the line while the command stands still is on the path (distance 0),
    the same 0.08 mm *across* it is a contour error of 0.08 mm. With a window of ±W raw
    samples the standstill shrank the polyline to a point and both read 0.08 mm."""
    v, ts = 20.0, TS
    x = np.concatenate([np.arange(0, 100) * v * ts, np.full(200, 100 * v * ts),
                        100 * v * ts + np.arange(1, 100) * v * ts])
    cmd = np.column_stack([x, np.zeros_like(x)])
    k = 150  # in the standstill
    W = int(round(m.CONTOUR_WINDOW_S / ts))
    along = cmd[k] + [0.08, 0.0]
    across = cmd[k] + [0.0, 0.08]
    got = m.distance_to_polyline_window(np.array([along, across]), cmd, W,
                                        index=np.array([k, k]))
    np.testing.assert_allclose(got, [0.0, 0.08], atol=1e-12)
    raw = m.distance_to_polyline_window(np.array([along]), cmd, W, index=np.array([k]),
                                        min_step_mm=0.0)
    assert raw[0] == pytest.approx(0.08)


def test_thinning_keeps_corners_and_both_ends():
    t = np.linspace(0.0, 1.0, 201)
    poly = np.vstack([np.column_stack([t, 0 * t]), np.column_stack([1 + 0 * t[1:], t[1:]])])
    kept, at = m.thin_polyline(poly, 0.05)
    assert kept[0] == 0 and kept[-1] == poly.shape[0] - 1
    assert 200 in kept  # the corner at (1, 0)
    assert np.all(np.diff(kept) > 0) and at.shape == (poly.shape[0],)
    assert kept.size < 0.3 * poly.shape[0]


def _thin_one_pass(Q, step, turn_deg=m.KEEP_TURN_DEG):
    """The thinning as one pass over the whole polyline (the reference the chunked one must
    equal bit for bit)."""
    d = np.diff(Q, axis=0)
    seg = np.hypot(d[:, 0], d[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    keep = np.zeros(Q.shape[0], bool)
    keep[0] = keep[-1] = True
    bucket = np.floor(cum / step)
    keep[1:] |= bucket[1:] > bucket[:-1]
    mv = np.flatnonzero(seg > 0)
    a, b = d[mv[:-1]], d[mv[1:]]
    cos = np.sum(a * b, axis=1) / (seg[mv[:-1]] * seg[mv[1:]])
    keep[mv[1:][cos < np.cos(np.radians(turn_deg))]] = True
    return keep


@pytest.mark.parametrize("chunk", [1, 2, 3, 64, 1 << 20])
def test_chunked_thinning_equals_one_pass(chunk):
    """Whatever the chunk (the optimizer thins a whole file's samples at each check, in chunks
    to bound memory): the same vertices, including turns whose moving segments straddle a
    chunk boundary across stops (repeated vertices)."""
    rng = np.random.default_rng(7)
    K = 3000
    t = np.cumsum(rng.exponential(0.01, K))
    Q = np.round(np.column_stack([50 * np.cos(3 * t), 40 * np.sin(2 * t)]), 2)
    Q[rng.random(K) < 0.3] = Q[0]
    stops = rng.integers(1, K - 1, 40)
    Q[stops] = Q[stops - 1]
    want = _thin_one_pass(Q, m.MIN_STEP_MM)
    got = m._thin_mask(Q, m.MIN_STEP_MM, chunk=chunk)
    np.testing.assert_array_equal(got, want)
    kept, at = m.thin_polyline(Q)
    np.testing.assert_array_equal(kept, np.flatnonzero(want))
    np.testing.assert_array_equal(at, np.searchsorted(kept, np.arange(K), side="right") - 1)
