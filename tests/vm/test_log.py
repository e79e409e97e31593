"""Encoder log: round trip, the fast formatter against Python's, and refused files."""

from __future__ import annotations

import numpy as np
import pytest

from gcode_feedopt.errors import LogError
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
    ("t,x_cmd,y_cmd,x,y\n0,1,2,3,4\n0.002,1,2,3,4\n0.010,1,2,3,4\n", r"time step .* differs"),
])
def test_bad_logs_refused(tmp_path, content, match):
    p = tmp_path / "bad.csv"
    p.write_text(content)
    with pytest.raises(LogError, match=match):
        read_log(p)


def test_missing_file(tmp_path):
    with pytest.raises(LogError, match="cannot read the log"):
        read_log(tmp_path / "nope.csv")
