"""Encoder log: round trip, the fast formatter against Python's, and refused files."""

from __future__ import annotations

import numpy as np
import pytest

from gcode_feedopt.errors import LogError, LogWarning
from gcode_feedopt.vm.log import format_rows, read_log, write_log


def sample(K=1000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(K) * 0.002
    cmd = np.cumsum(rng.normal(size=(K, 3)), axis=0) * 3 - 50
    pos = cmd + rng.normal(scale=0.01, size=(K, 3))
    e = np.cumsum(np.abs(rng.normal(size=K)))
    return t, cmd, pos, e


def test_format_rows_matches_python_formatting():
    rng = np.random.default_rng(1)
    v = np.concatenate([rng.normal(scale=300, size=(500, 4)), rng.normal(scale=1e-5, size=(500, 4))])
    v[0] = [0.0, -0.0, 1e-7, -123456.789]
    text = format_rows(v).decode()
    expect = "".join(",".join(f"{x:.6f}" for x in row) + "\n" for row in v)
    # Python prints -0.000000 for tiny negatives; the log writes 0.000000 (same number)
    assert text == expect.replace("-0.000000", "0.000000")


def test_round_trip_all_columns(tmp_path):
    t, cmd, pos, e = sample()
    p = tmp_path / "log.csv"
    write_log(p, t, cmd, pos, e)
    assert p.read_text().splitlines()[0] == "t,x_cmd,y_cmd,x,y,z_cmd,z,e_cmd"
    log = read_log(p)
    np.testing.assert_allclose(log.t_s, t, atol=5e-7)
    np.testing.assert_allclose(log.cmd_mm, cmd, atol=5e-7)
    np.testing.assert_allclose(log.pos_mm, pos, atol=5e-7)
    np.testing.assert_allclose(log.e_cmd_mm, e, atol=5e-7)
    assert log.ts_s == pytest.approx(0.002, rel=1e-9)
    tr = log.trajectory()
    assert tr.n_samples == 1000 and tr.ts_s == pytest.approx(0.002)


def test_round_trip_minimal_columns(tmp_path):
    t, cmd, pos, _ = sample(50)
    p = tmp_path / "log.csv"
    write_log(p, t, cmd, pos, include_z=False)
    log = read_log(p)
    assert log.columns == ("t", "x_cmd", "y_cmd", "x", "y") and log.e_cmd_mm is None
    np.testing.assert_array_equal(log.cmd_mm[:, 2], 0.0)
    np.testing.assert_allclose(log.pos_mm[:, :2], pos[:, :2], atol=5e-7)


def test_columns_in_any_order(tmp_path):
    """A logger that writes measured before commanded columns (or t last) is read by name."""
    t, cmd, pos, _ = sample(50)
    p = tmp_path / "log.csv"
    write_log(p, t, cmd, pos, include_z=False)
    ref = read_log(p)
    rows = np.loadtxt(p, delimiter=",", skiprows=1)
    q = tmp_path / "reordered.csv"
    np.savetxt(q, rows[:, [3, 4, 1, 2, 0]], delimiter=",", fmt="%.6f",
               header="x,y,x_cmd,y_cmd,t", comments="")
    log = read_log(q)
    np.testing.assert_array_equal(log.cmd_mm, ref.cmd_mm)
    np.testing.assert_array_equal(log.pos_mm, ref.pos_mm)
    np.testing.assert_array_equal(log.t_s, ref.t_s)


@pytest.mark.parametrize("content, match", [
    ("#time,accel_x,accel_y,accel_z\n1,2,3,4\n", r":1: header .* raw Klipper accelerometer"),
    ("t,x_cmd,y_cmd,x,y,e_cmnd\n0,1,2,3,4,5\n", r"unknown column 'e_cmnd' \(did you mean 'e_cmd'\?\)"),
    ("t,x_cmd,y_cmd,x,z\n0,1,2,3,4\n0.002,1,2,3,4\n", r":1: header .* lacks column\(s\) y;"),
    ("t,x_cmd,y_cmd,x,y\n0,1,2,3,4\n0.002,1,2,3\n", r":3: 4 values, the header has 5"),
    ("t,x_cmd,y_cmd,x,y\n0,1,2,3,4\n0.002,1,2,abc,4\n", r":3: .* is not a row of numbers"),
    ("t,x_cmd,y_cmd,x,y\n0,1,2,3,4\n", r"1 data rows; a log needs at least 2"),
    ("t,x_cmd,y_cmd,x,y\n" + "".join(f"{0.002 * k + 0.01 * (k > 5):.6f},1,2,3,4\n"
                                      for k in range(12)), r":8: a gap of 12 ms after t=0.01 s"),
    ("t,x_cmd,y_cmd,x,y\n0,1,2,3,4\n0.002,1,2,3,4\n0.002,1,2,3,4\n0.004,1,2,3,4\n",
     r":4: time 0.002 s does not follow 0.002 s"),
    ("t,x_cmd,y_cmd,x,y\n" + "".join(f"{0.002 * k + 0.0015 * (k == 5):.6f},1,2,3,4\n"
                                      for k in range(5)) + "0.0085,1,2,3,4\n0.010,1,2,3,4\n",
     r":7: time step 0.0005 s, the log's usual step is 0.002 s"),
])
def test_bad_logs_refused(tmp_path, content, match):
    p = tmp_path / "bad.csv"
    p.write_text(content)
    with pytest.raises(LogError, match=match):
        read_log(p)


def test_missing_file(tmp_path):
    with pytest.raises(LogError, match="cannot read the log"):
        read_log(tmp_path / "nope.csv")


def smooth(t):
    """A planner-like smooth command and a lagging, ringing response (mm)."""
    cmd = np.column_stack([40 * np.sin(2 * np.pi * 0.7 * t), 30 * np.cos(2 * np.pi * 1.1 * t)])
    pos = cmd + 0.05 * np.column_stack([np.sin(2 * np.pi * 40 * t), np.cos(2 * np.pi * 35 * t)])
    return cmd, pos


def write_rows(p, t, cmd, pos):
    rows = np.column_stack([t, cmd, pos])
    np.savetxt(p, rows, delimiter=",", header="t,x_cmd,y_cmd,x,y", comments="", fmt="%.6f")


def test_values_at_jittered_times_are_interpolated_on_the_grid(tmp_path):
    """A logger that samples when it can: ±0.4 ms of jitter on 2 ms, 7 samples dropped. The
    log comes back on the 2 ms grid, each column interpolated at the logged times: within
    linear interpolation's error of the truth, where taking the rows as uniform errs by
    v·δt."""
    rng = np.random.default_rng(3)
    K, ts = 1500, 0.002
    t = np.arange(K) * ts + np.r_[0, rng.uniform(-4e-4, 4e-4, K - 2), 0]
    keep = np.ones(K, bool)
    keep[rng.choice(np.arange(10, K - 10), 7, replace=False)] = False
    t = np.round(t[keep], 6)
    cmd, pos = smooth(t)
    p = tmp_path / "jit.csv"
    write_rows(p, t, cmd, pos)
    with pytest.warns(LogWarning, match=r"not uniform .*off a 2 ms grid, 7 sample\(s\) missing"
                      r"\): every column interpolated on that grid at the logged times"):
        log = read_log(p)
    assert log.t_s.size == K and log.ts_s == pytest.approx(ts, abs=1e-9)
    c, q = smooth(np.arange(K) * ts)
    assert np.max(np.abs(log.cmd_mm[:, :2] - c)) < 0.02      # a·h²/8 at 4 ms: 5 µm + rounding
    assert np.max(np.abs(log.pos_mm[:, :2] - q)) < 0.03
    # the rows taken as uniform would be off by up to v·δt (175 mm/s × 0.4 ms ≈ 70 µm) and
    # shifted by the dropped samples
    assert np.max(np.abs(cmd[:200] - c[:200])) > 0.03


def test_jittered_stamps_of_uniform_samples_keep_the_rows(tmp_path):
    """A logger that stamps a timer's samples late or early: the values lie on the uniform
    grid, the commands run smoothly row by row, so the rows are kept as they are (one
    dropped sample filled in by interpolation), not moved to the stamps' times."""
    rng = np.random.default_rng(4)
    K, ts = 1500, 0.002
    tu = np.arange(K) * ts
    cmd, pos = smooth(tu)
    stamps = np.round(tu + np.r_[0, rng.uniform(-4e-4, 4e-4, K - 2), 0], 6)
    keep = np.ones(K, bool)
    keep[700] = False
    p = tmp_path / "stamps.csv"
    write_rows(p, stamps[keep], cmd[keep], pos[keep])
    with pytest.warns(LogWarning, match=r"1 sample\(s\) missing\): the rows taken as that "
                      r"grid's samples .*stamps of uniform samples\), the missing ones interpolated"):
        log = read_log(p)
    assert log.t_s.size == K
    np.testing.assert_allclose(np.delete(log.cmd_mm[:, :2], 700, 0), cmd[keep], atol=1e-6)
    np.testing.assert_allclose(log.pos_mm[700, :2], 0.5 * (pos[699] + pos[701]), atol=1e-6)


def test_a_uniform_log_is_read_as_written(tmp_path):
    """Within print round-off the grid check passes and no warning is issued (the jitter
    branch never touches a uniform log)."""
    import warnings

    t, cmd, pos, e = sample()
    p = tmp_path / "log.csv"
    write_log(p, t, cmd, pos, e)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        log = read_log(p)
    np.testing.assert_array_equal(log.t_s, np.loadtxt(p, delimiter=",", skiprows=1)[:, 0])
