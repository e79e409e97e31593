"""The Klipper firmware model against real Klipper: the referee's times, recorded by
benchmarks/klipper_referee.py from Klipper's own planner (batch mode, the commit and printer.cfg
in tests/vm/data/klipper_referee/referee.json), must be met within 0.5 % on the same bytes
(issue 20's three files as sliced and as our output, and an ArcWelder file's arcs). No
Klipper is needed here: the inputs are cut from ../shared/data at test time (their SHA-256
checked against the recorded one) and our outputs that Klipper timed are stored (.xz)."""

from __future__ import annotations

import importlib.util
import json
import lzma
import re

import pytest

from gcode_feedopt.profile import load_profile

from ..conftest import REPO

SCRIPT = REPO / "benchmarks" / "klipper_referee.py"
_spec = importlib.util.spec_from_file_location("klipper_referee", SCRIPT)
referee = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(referee)

RECORD = json.loads(referee.RECORD.read_text())
PROFILE = load_profile(referee.PROFILE)
#: issue 20's target: the model within 0.5 % of real Klipper
TOLERANCE = 0.005
#: what the model achieves (the same rules, so the same time to round-off): a change that
#: loosens this must say why
EXACT = 1e-5


def _case_bytes(case: str) -> bytes:
    name, kind = case.split("/")
    if kind == "original":
        src = referee.SOURCES[name]
        if not src.exists():
            pytest.skip(f"{src} not found")
        return referee.prepare(src, RECORD["lines"])
    return lzma.decompress((referee.DATA_DIR / f"{name}.out.gcode.xz").read_bytes())


@pytest.mark.parametrize("case", sorted(RECORD["cases"]))
def test_model_times_the_file_as_klipper_does(case):
    rec = RECORD["cases"][case]
    data = _case_bytes(case)
    assert referee.sha256(data) == rec["sha256"], (
        f"{case}: not the bytes the referee timed; re-record with benchmarks/klipper_referee.py")
    model = referee.model_time_s(data, PROFILE)
    assert abs(model / rec["referee_s"] - 1.0) <= TOLERANCE, (case, model, rec["referee_s"])
    assert abs(model / rec["referee_s"] - 1.0) <= EXACT, (case, model, rec["referee_s"])


def test_every_case_recorded():
    names = ({f"{n}/original" for n in referee.SOURCES}
             | {f"{n}/output" for n in referee.WITH_OUTPUT})
    assert set(RECORD["cases"]) == names and len(names) == 7
    assert re.fullmatch(r"[0-9a-f]{40}", RECORD["klipper_commit"])


def _cfg(text: str) -> dict:
    """printer.cfg as {section: {key: value}} (enough for the referee's file)."""
    out, sec = {}, None
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if line.startswith("[") and line.endswith("]"):
            sec = out.setdefault(line[1:-1], {})
        elif ":" in line and sec is not None:
            k, v = line.split(":", 1)
            sec[k.strip()] = v.strip()
    return out


def test_profile_is_the_referee_printer():
    """klipper300.yaml states the printer.cfg Klipper ran with (defaults: Klipper's)."""
    cfg = _cfg(RECORD["printer_cfg"])
    pr, ex = cfg["printer"], cfg["extruder"]
    fw = PROFILE.firmware
    assert pr["kinematics"] == "cartesian" and fw.flavour == "klipper"
    assert float(pr["max_velocity"]) == fw.max_feed_mm_s["x"] == fw.max_feed_mm_s["y"]
    assert float(pr["max_accel"]) == fw.accel_mm_s2 == fw.travel_accel_mm_s2
    assert float(pr.get("minimum_cruise_ratio", 0.5)) == fw.minimum_cruise_ratio
    assert float(pr.get("square_corner_velocity", 5.0)) == fw.square_corner_velocity_mm_s
    assert float(pr["max_z_velocity"]) == fw.max_feed_mm_s["z"]
    assert float(pr["max_z_accel"]) == fw.max_accel_mm_s2["z"]
    assert float(ex["max_extrude_only_velocity"]) == fw.max_feed_mm_s["e"]
    assert float(ex["max_extrude_only_accel"]) == fw.max_accel_mm_s2["e"]
    assert float(ex.get("instantaneous_corner_velocity", 1.0)) == \
        fw.instantaneous_corner_velocity_mm_s
    assert float(cfg["gcode_arcs"].get("resolution", 1.0)) == fw.mm_per_arc_segment


@pytest.mark.parametrize("name, lines", [("butterfly", 20000), ("prusa_mini_benchy", 4000),
                                         ("cura_benchy", 4000)])
def test_kinematic_plan_runs_as_planned_on_klipper(tmp_path, name, lines):
    """The kinematic plan follows the same Klipper rules (plan.kinematic), so our firmware
    model — Klipper, above — runs the written file in the plan's time, and plans the file as
    sliced as the planner does (report: input_time_same_limits_s)."""
    from gcode_feedopt.pipeline import Options, optimize_file

    src = referee.SOURCES[name]
    if not src.exists():
        pytest.skip(f"{src} not found")
    inp = tmp_path / "in.gcode"
    inp.write_bytes(referee.prepare(src, lines))
    # the machine's speeds (at the slicer's the kinematic plan is the file's own; the first
    # layer keeps its speeds under both: the butterfly and the Cura excerpt are all first layer)
    rep = optimize_file(inp, tmp_path / "out.gcode", PROFILE,
                        Options(method="kinematic", speed="machine"))
    assert "kept_input" not in rep.extra
    assert rep.output_time_s == pytest.approx(rep.plan_time_s, rel=1e-5, abs=2e-3)
    # at the same accelerations: the plan's, which override the file's lower ones (the MINI's
    # M204 P1250 T2500, Klipper 1250) under --accel plan; as sliced elsewhere
    assert rep.extra["input_time_same_limits_s"] == pytest.approx(
        rep.extra["input_time_plan_accel_s"], rel=1e-9)
    assert rep.output_time_s <= rep.input_time_s * (1 + 1e-6)
