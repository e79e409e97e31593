import warnings

import numpy as np
import pytest
from click.testing import CliRunner

from gcode_feedopt.cli import cli
from gcode_feedopt.twin.contour import chance_bounds, contour_distribution, geometric_contour_error


def write_log(path, n=1500, measured=True, ts=0.002):
    t = np.arange(n) * ts
    x = 40 * np.clip(t - 0.5, 0, 1)
    y = 10 * np.sin(2 * t)
    cols = [t, x, y] + ([x + 0.02, y] if measured else [])
    with open(path, "w") as fh:
        fh.write("t,x_cmd,y_cmd" + (",x,y" if measured else "") + "\n")
        np.savetxt(fh, np.column_stack(cols), delimiter=",", fmt="%.6f")


@pytest.mark.parametrize("measured", [True, False])
def test_predict_writes_columns(tmp_path, measured):
    log = tmp_path / "log.csv"
    write_log(log, measured=measured)
    out = tmp_path / "pred.csv"
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        res = CliRunner().invoke(cli, ["predict", "--machine", "ender3pro", str(log), "-o",
                                       str(out)])
    assert res.exit_code == 0, res.output
    lines = out.read_text().splitlines()
    assert lines[0] == "t,x_mean,x_std,y_mean,y_std" and len(lines) == 1501
    arr = np.loadtxt(out, delimiter=",", skiprows=1)
    assert np.all(arr[:, 2] > 0) and np.all(arr[:, 4] > 0)
    said = [str(w.message) for w in rec if "sensor's zero" in str(w.message)]
    if measured:  # x reads 0.02 mm high at rest too: the sensor's zero, subtracted
        assert len(said) == 1 and "x by +0.0200 mm" in said[0]
        assert abs(arr[-1, 1] - 40.0) < 0.005
    else:
        assert not said


def test_predict_refuses_bad_logs(tmp_path):
    log = tmp_path / "log.csv"
    write_log(log, ts=0.004)  # another logger's period: resampled to Ts, with a warning
    from gcode_feedopt.errors import LogWarning

    with pytest.warns(LogWarning, match="sampled every 4 ms.*resampled"):
        res = CliRunner().invoke(cli, ["predict", "--machine", "ender3pro", str(log), "-o",
                                       str(tmp_path / "p.csv")])
    assert res.exit_code == 0
    log.write_text("t,x,y\n0,1,2\n")
    res = CliRunner().invoke(cli, ["predict", "--machine", "ender3pro", str(log), "-o",
                                   str(tmp_path / "p.csv")])
    assert res.exit_code != 0 and "x_cmd" in res.output


def test_geometric_contour_error_circle():
    t = np.linspace(0, 2 * np.pi, 4001)
    P = np.c_[10 * np.cos(t), 10 * np.sin(t)]
    Q = np.c_[10.05 * np.cos(t[::13] + 1e-3), 10.05 * np.sin(t[::13] + 1e-3)]
    np.testing.assert_allclose(geometric_contour_error(P, Q), 0.05, atol=1e-4)


def test_contour_distribution_signs():
    # moving +x: the contour error is the y error; both chance bounds are reported
    xd = np.linspace(0, 10, 100)
    yd = np.zeros(100)
    m, s = contour_distribution(xd, yd, xd, np.full(100, 0.01), yd - 0.03, np.full(100, 0.02))
    np.testing.assert_allclose(m[5:-5], 0.03)
    np.testing.assert_allclose(s[5:-5], 0.02)
    hi, lo = chance_bounds(m, s, 0.95)
    np.testing.assert_allclose(hi[5:-5], 0.03 + 1.6448536 * 0.02, rtol=1e-6)
    np.testing.assert_allclose(lo[5:-5], 0.03 - 1.6448536 * 0.02, rtol=1e-6)
