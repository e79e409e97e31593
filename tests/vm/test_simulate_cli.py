"""``gcode-feedopt simulate``: option errors, and end to end on the shared G-code files.

The end-to-end tests need the reader, the firmware model, the profiles and the twin's FRF
draws (other stages); they are skipped with the reason while any of those is missing.
"""

from __future__ import annotations

import importlib
import json

import numpy as np
import pytest
from click.testing import CliRunner

from gcode_feedopt.cli import cli

DEPENDENCIES = ("gcode_feedopt.gcode.reader", "gcode_feedopt.vm.firmware", "gcode_feedopt.profile",
                "gcode_feedopt.twin.frf")


def _missing():
    out = []
    for name in DEPENDENCIES:
        try:
            importlib.import_module(name)
        except ImportError:
            out.append(name)
    return out


needs_stages = pytest.mark.skipif(bool(_missing()), reason=f"stages not landed yet: {_missing()}")

SQUARE_TOWER = "cura-4.8_ender3_square-tower.gcode"


def test_bad_effect_spec_is_a_usage_error(tmp_path):
    g = tmp_path / "a.gcode"
    g.write_text("G1 X1 Y1 F600\n")
    res = CliRunner().invoke(cli, ["simulate", str(g), "--machine", "ender3pro", "--effect", "sinus:axis=x"])
    assert res.exit_code == 2
    assert "did you mean 'sinusoid'" in res.output


def first_layers(src, dst, n_layers=2):
    """Cut the file after its n-th ;LAYER: comment (an excerpt cut at test time)."""
    out = []
    seen = 0
    for line in src.read_text().splitlines(keepends=True):
        if line.startswith(";LAYER:"):
            seen += 1
            if seen > n_layers:
                break
        out.append(line)
    dst.write_text("".join(out))
    return dst


def run_simulate(args):
    res = CliRunner().invoke(cli, ["simulate", *args], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    return res


@needs_stages
def test_simulate_excerpt_log_and_report(data_dir, tmp_path):
    from gcode_feedopt.vm.log import read_log

    g = first_layers(data_dir / "gcode" / SQUARE_TOWER, tmp_path / "tower2.gcode")
    log, rep = tmp_path / "log.csv", tmp_path / "rep.json"
    res = run_simulate([str(g), "--machine", "ender3pro", "--seed", "1", "--log", str(log),
                        "--report", str(rep), "--effect", "noise:axis=x,std_mm=0.001"])
    assert "cycle time" in res.output
    report = json.loads(rep.read_text())
    for key in ("cycle_time_s", "rms_gamma_mm", "within_fraction", "max_contour_error_mm"):
        assert key in report
    assert report["effects"] == [{"kind": "noise", "axis": "x", "params": {"std_mm": 0.001}}]
    lg = read_log(log)
    assert lg.columns == ("t", "x_cmd", "y_cmd", "x", "y", "z_cmd", "z", "e_cmd")
    assert (lg.t_s.size - 1) * lg.ts_s == pytest.approx(report["cycle_time_s"], abs=1e-6)
    # the machine moved: commanded XY spans the first layers' footprint
    assert np.ptp(lg.cmd_mm[:, 0]) > 10
    # the same seed without the noise effect: the same machine, so the logs differ by the
    # noise on x only (std 1 um; 5 standard errors of a sample std allowed)
    log0 = tmp_path / "log0.csv"
    run_simulate([str(g), "--machine", "ender3pro", "--seed", "1", "--log", str(log0), "-q"])
    clean = read_log(log0)
    np.testing.assert_array_equal(clean.pos_mm[:, 1], lg.pos_mm[:, 1])
    noise = lg.pos_mm[:, 0] - clean.pos_mm[:, 0]
    assert noise.std() == pytest.approx(0.001, rel=5 / np.sqrt(2 * noise.size) + 0.01)


@needs_stages
def test_same_seed_same_run_and_effect_changes_it(data_dir, tmp_path):
    g = first_layers(data_dir / "gcode" / SQUARE_TOWER, tmp_path / "tower1.gcode", 1)
    reps = []
    for i, extra in enumerate([[], [], ["--effect", "sinusoid:axis=x"]]):
        rep = tmp_path / f"r{i}.json"
        run_simulate([str(g), "-m", "ender3pro", "--seed", "3", "--report", str(rep), "-q", *extra])
        reps.append(json.loads(rep.read_text()))
    assert reps[0]["rms_contour_error_mm"] == reps[1]["rms_contour_error_mm"]
    # the paper's 0.2 mm sinusoid on x raises the RMS contour error
    assert reps[2]["rms_contour_error_mm"] > reps[0]["rms_contour_error_mm"] + 0.05


@needs_stages
@pytest.mark.slow
@pytest.mark.parametrize("name", ["cura-4.11_ender3_3dbenchy.gcode", "cura-4.8_ender3_square-tower.gcode",
                                  "prusaslicer-2.6.1_mini_3dbenchy.gcode", "slic3rpe-arcwelder_3dbenchy-arcs.gcode"])
def test_simulate_every_shared_file(data_dir, tmp_path, name):
    rep = tmp_path / "r.json"
    run_simulate([str(data_dir / "gcode" / name), "-m", "ender3pro", "--report", str(rep), "-q"])
    report = json.loads(rep.read_text())
    assert report["cycle_time_s"] > 600  # every one is a print of more than 10 minutes
    assert 0 <= report["within_fraction"] <= 1 and report["n_evaluated"] > 0
