"""Tolerance per slicer feature (issue 20 point 5): tags, fallback, validation, the plan."""

from __future__ import annotations

import collections

import numpy as np
import pytest
from click.testing import CliRunner

from gcode_feedopt.cli import cli
from gcode_feedopt.errors import FeedOptError, ProfileError
from gcode_feedopt.gcode.features import (FEATURES, TAG_TO_FEATURE, canonical,
                                          parse_feature_tolerance, tag_of)
from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.pipeline import Options, path_for, plan, read_for, run_settings, tolerance_for
from gcode_feedopt.plan.request import PlanRequest
from gcode_feedopt.profile import load_profile

from ..conftest import GCODE_DIR

CURA = GCODE_DIR / "cura-4.11_ender3_3dbenchy.gcode"
PRUSA = GCODE_DIR / "prusaslicer-2.6.1_mini_3dbenchy.gcode"
UNTAGGED = GCODE_DIR / "slic3rpe-arcwelder_3dbenchy-arcs.gcode"

pytestmark = pytest.mark.skipif(not CURA.is_file(), reason=f"reference data not found at {CURA}")


def _head(path, n):
    with open(path, "rb") as fh:
        return b"".join(fh.readline() for _ in range(n))


def _features(path, n=20000):
    prog = read_program(_head(path, n), path.name)
    return collections.Counter(m.feature for m in prog.moves)


def test_table_maps_to_canonical_features_only():
    assert set(TAG_TO_FEATURE.values()) <= set(FEATURES)
    assert tag_of(";TYPE:WALL-OUTER\n") == "WALL-OUTER"
    assert tag_of(";TYPE:External perimeter\r\n") == "EXTERNAL PERIMETER"
    assert tag_of("; FEATURE: Outer wall\n") == "OUTER WALL"
    assert tag_of(";LAYER:3\n") is None and tag_of("G1 X1 ;TYPE:FILL") is None
    assert canonical("Internal infill") == "infill"
    assert canonical("SOMETHING NEW") == "other"


def test_cura_tags():
    c = _features(CURA)
    for f in ("outer_wall", "inner_wall", "skin", "infill", "skirt", "travel"):
        assert c[f] > 0, (f, c)
    assert c[""] <= 5  # the purge line before the first ;TYPE:


def test_prusaslicer_tags():
    c = _features(PRUSA, 60000)
    for f in ("outer_wall", "inner_wall", "skin", "infill", "bridge", "travel"):
        assert c[f] > 0, (f, c)


def test_untagged_file_falls_back_to_one_tolerance():
    profile = load_profile("ender3pro")
    prog = read_program(_head(UNTAGGED, 3000), UNTAGGED.name, flavour="marlin")
    assert {m.feature for m in prog.moves} <= {"", "travel"}
    path = path_for(prog, profile)
    req = PlanRequest.from_options(profile, Options(feature_tolerance={"outer_wall": 0.05}))
    tol, _, notes = tolerance_for(path, prog, req)
    assert np.ndim(tol) == 0 and tol == profile.limits.tolerance_mm
    assert len(notes) == 1 and "no slicer feature tags" in notes[0]


def test_parse_and_validation():
    assert parse_feature_tolerance("outer_wall=0.05, infill=0.3") == {"outer_wall": 0.05,
                                                                      "infill": 0.3}
    assert parse_feature_tolerance("off") == {}
    assert parse_feature_tolerance(None) is None
    d = parse_feature_tolerance("defaults,infill=0.4,travel=none")
    assert d["outer_wall"] == 0.05 and d["infill"] == 0.4 and d["travel"] == float("inf")
    for bad in ("wall=0.1", "infill=-1", "infill=abc", "infill"):
        with pytest.raises(FeedOptError) as e:
            parse_feature_tolerance(bad)
        assert "\n" not in str(e.value)


def test_cli_unknown_feature_is_one_line_exit_2(tmp_path):
    src = tmp_path / "a.gcode"
    src.write_bytes(_head(CURA, 400))
    r = CliRunner().invoke(cli, [str(src), "-o", str(tmp_path / "b.gcode"), "-m", "ender3pro",
                                 "--feature-tolerance", "outerwall=0.05"])
    assert r.exit_code == 2
    assert "unknown feature 'outerwall'" in r.output
    assert not (tmp_path / "b.gcode").exists()


def test_profile_validation(tmp_path):
    from gcode_feedopt.profile.io import profile_to_dict, parse_profile
    p = load_profile("ender3pro")
    d = profile_to_dict(p)
    d["limits"]["feature_tolerance_mm"] = {"outer_wall": 0.05, "travel": "none"}
    q = parse_profile(d, "x.yaml", None)
    assert q.limits.feature_tolerance_mm == {"outer_wall": 0.05, "travel": float("inf")}
    assert profile_to_dict(q)["limits"]["feature_tolerance_mm"]["travel"] == "none"
    d["limits"]["feature_tolerance_mm"] = {"walls": 0.05}
    with pytest.raises(ProfileError, match="unknown feature 'walls'"):
        parse_profile(d, "x.yaml", None)
    d["limits"]["feature_tolerance_mm"] = 0.05
    with pytest.raises(ProfileError, match="must be a mapping"):
        parse_profile(d, "x.yaml", None)


@pytest.fixture(scope="module")
def cura_excerpt(tmp_path_factory):
    """The first 6000 lines of the real Cura Benchy: skirt, walls, skin and the first infill."""
    src = tmp_path_factory.mktemp("ft") / "benchy6k.gcode"
    src.write_bytes(_head(CURA, 6000))
    profile = load_profile("ender3pro")
    prog = read_for(src, profile)
    return profile, prog, path_for(prog, profile)


def _plan(cura_excerpt, table):
    profile, prog, path = cura_excerpt
    req = PlanRequest.from_options(profile, Options(method="pidd", tolerance_mm=0.1,
                                                    feature_tolerance=table))
    tol, feats, _ = tolerance_for(path, prog, req)
    return plan(path, profile, req, tolerance=tol), tol, feats


@pytest.fixture(scope="module")
def scalar_plan(cura_excerpt):
    return _plan(cura_excerpt, {})


def test_scalar_path_identity(cura_excerpt, scalar_plan):
    """Per feature off: the scalar goes in; an array of that same value everywhere takes the
    per-sample code and plans the same samples."""
    sched, tol, feats = scalar_plan
    assert np.ndim(tol) == 0
    profile, prog, path = cura_excerpt
    arr = np.full(path.n_segments, 0.1)
    same = plan(path, profile, PlanRequest.from_options(profile, Options(method="pidd")),
                tolerance=arr)
    assert np.array_equal(same.s_mm, sched.s_mm)
    assert "outer_wall" not in run_settings(profile, Options())


def test_looser_infill_is_no_slower(cura_excerpt, scalar_plan):
    base = scalar_plan[0]
    loose, tol, feats = _plan(cura_excerpt, {"infill": 0.3})
    assert np.any(feats == "infill")
    assert loose.duration_s <= base.duration_s + 1e-9


def test_tight_outer_wall_holds_its_tolerance(cura_excerpt, scalar_plan):
    sched, tol, feats = _plan(cura_excerpt, {"outer_wall": 0.05})
    path = cura_excerpt[2]
    b = np.asarray(sched.info["predicted_bound_mm"])
    mot = np.asarray(sched.info["predicted_motion_mm"])
    seg = path.segment_at(sched.s_mm[:b.size])
    outer = feats[seg] == "outer_wall"
    assert outer.any()
    # the outer wall's every predicted mean within its 0.05 mm; its bound there too but for
    # the samples the stringency's budget carries (optimize.slowdown.budget)
    assert float(np.max(mot[outer])) <= 0.05 + 1e-9
    assert sched.info["relaxed_samples"] == 0
    tol_k = np.asarray(tol)[seg]
    assert np.sum(b > tol_k) == sched.info["budget_samples"]
    base_b = np.asarray(scalar_plan[0].info["predicted_bound_mm"])
    base_outer = scalar_plan[2][path.segment_at(scalar_plan[0].s_mm[:base_b.size])] == "outer_wall"
    assert float(np.max(base_b[base_outer])) > 0.05  # the single 0.1 mm would not have held it
    assert sched.duration_s >= scalar_plan[0].duration_s - 1e-9
