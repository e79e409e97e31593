"""Where the time went (issue 20 point 6): the report's split sums to the saving exactly, the
feed term is zero at the slicer's speeds, and only the twin's term is the optimizer's."""

from __future__ import annotations

import dataclasses

import pytest

from gcode_feedopt.pipeline import Options, optimize_file
from gcode_feedopt.profile import load_profile

from .conftest import GCODE_DIR, REPO

KEYS = ("limits", "feed", "junctions", "twin", "firmware_vs_plan")


def _split(src, tmp_path, **opts):
    rep = optimize_file(src, tmp_path / "out.gcode", load_profile("ender3pro"),
                        Options(allow_slower=True, **opts))
    sp = rep.extra["time_split_s"]
    assert set(sp) == set(KEYS)
    assert sum(sp.values()) == pytest.approx(rep.output_time_s - rep.input_time_s, abs=1e-6)
    # the plan's junctions (ender3pro's hardware speed step) are never slower than the file's
    assert sp["junctions"] <= 0.0
    return rep, sp


def test_split_at_the_slicer_speeds(tmp_path):
    rep, sp = _split(REPO / "sample_gcode" / "butterfly.gcode", tmp_path)
    assert abs(sp["feed"]) < 1e-6  # no move above its sliced F: the same firmware plan
    assert sp["limits"] < 0  # ender3pro is configured at 500 mm/s², the plan runs 3000
    assert sp["twin"] >= 0.0
    assert "where the time went" in rep.summary()


def test_kinematic_has_no_twin_term(tmp_path):
    _, sp = _split(REPO / "sample_gcode" / "butterfly.gcode", tmp_path, method="kinematic")
    assert sp["twin"] == 0.0


def test_the_twins_term_is_its_slow_downs(tmp_path):
    """A tolerance the firmware's plan breaks (0.03 mm on the butterfly): the twin's term is
    what the slow-downs cost, the plan's time over the firmware's own."""
    rep, sp = _split(REPO / "sample_gcode" / "butterfly.gcode", tmp_path, tolerance_mm=0.03)
    assert rep.extra["slowed_length_fraction"] > 0
    assert sp["twin"] > 0


@pytest.mark.shared_data
def test_split_under_machine_speeds(tmp_path):
    """First 20,000 lines of the Cura Benchy, kinematic, --speed machine: the feed term is
    the saving above the sliced F (first layer excepted), the limits' the raised acceleration."""
    src = tmp_path / "head.gcode"
    lines = (GCODE_DIR / "cura-4.11_ender3_3dbenchy.gcode").read_bytes().splitlines(True)
    src.write_bytes(b"".join(lines[:20_000]))
    _, sp = _split(src, tmp_path, speed="machine", method="kinematic")
    assert sp["feed"] < 0 and sp["limits"] < 0 and sp["twin"] == 0.0
    assert abs(sp["firmware_vs_plan"]) < 0.01 * abs(sp["feed"])


def test_the_junction_term_is_zero_where_the_files_junctions_are_kept(tmp_path):
    """--accel file keeps the firmware's and the file's junction settings, and so does a
    profile that states no hardware junction limit: no junction term either way."""
    src = REPO / "sample_gcode" / "butterfly.gcode"
    _, sp = _split(src, tmp_path, accel="file")
    assert sp["junctions"] == 0.0
    prof = load_profile("ender3pro")
    prof = dataclasses.replace(prof, limits=dataclasses.replace(prof.limits, axis_jerk_mm_s=None))
    rep = optimize_file(src, tmp_path / "out.gcode", prof, Options(allow_slower=True))
    assert rep.extra["time_split_s"]["junctions"] == 0.0
    assert "the firmware's rule kept" in rep.summary()
    assert "accel plan (the plan's accelerations over the file's)" in rep.summary()
    rep, _ = _split(src, tmp_path)
    assert "accel plan (the plan's accelerations and junctions over the file's)" in rep.summary()
