"""Issue 19, point 4, as both the benchA and the foreign tests check it: ``diagnose -o``
writes a profile, ``predict --no-learn`` runs it on the same log, and the held-out RMS of
that prediction is set against what ``diagnose`` reported."""

from __future__ import annotations

import json

import numpy as np
from click.testing import CliRunner

from gcode_feedopt.cli import cli


def diagnose_then_predict(base_yaml, log, tmp_path) -> tuple[dict, dict]:
    """(diagnose's JSON, {axis: held-out RMS mm of the written profile's prediction})."""
    r = CliRunner().invoke(cli, ["diagnose", "-m", str(base_yaml), str(log), "--json",
                                 str(tmp_path / "d.json"), "-o", str(tmp_path / "ext.yaml")])
    assert r.exit_code == 0, r.output
    d = json.loads((tmp_path / "d.json").read_text())
    r = CliRunner().invoke(cli, ["predict", "-m", str(tmp_path / "ext.yaml"), str(log), "-o",
                                 str(tmp_path / "p.csv"), "--no-learn"])
    assert r.exit_code == 0, r.output
    pred = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1)
    meas = np.loadtxt(log, delimiter=",", skiprows=1)
    k = d["fit_samples"]
    rms = {ax: float(np.sqrt(np.mean((meas[k:, 3 + i] - pred[k:, 1 + 2 * i]) ** 2)))
           for i, ax in enumerate("xy")}
    return d, rms
