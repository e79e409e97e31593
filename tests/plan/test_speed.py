"""The speed policy (issue 20 point 1): by default no move is faster than its sliced F, on
every real file; ``--speed machine`` keeps the first layer and the hotend's volumetric limit."""

import math
import pathlib

import numpy as np
import pytest
from click.testing import CliRunner

from gcode_feedopt import firmware
from gcode_feedopt.cli import cli
from gcode_feedopt.gcode.path import build_path
from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.gcode.writer import T_NEW, write
from gcode_feedopt.pipeline import Options, path_for, plan, read_for
from gcode_feedopt.plan.request import PlanRequest
from gcode_feedopt.plan.kinematic import writer_accel
from gcode_feedopt.plan.speed import feed_ceiling, plan_vmax, planning_path
from gcode_feedopt.profile import load_profile

REPO = pathlib.Path(__file__).resolve().parents[2]
REAL = REPO.parent / "shared" / "data" / "gcode"
PROFILE = load_profile("ender3pro")
#: lines of each real file checked (the first layers: first-layer speeds, walls, infill,
#: travels, retractions, cooling slow-downs of small layers show up early in a Benchy)
HEAD_LINES = 20_000


def real_files():
    files = sorted(REAL.glob("*.gcode")) + sorted((REPO / "sample_gcode").glob("*.gcode"))
    assert len(files) >= 5
    return files


def _f_word(line: bytes):
    for tok in line.split(b";", 1)[0].split():
        if tok[:1] in (b"F", b"f"):
            return float(tok[1:])
    return None


CASES = [(f, "kinematic") for f in real_files()] + [
    (f, "pidd") for f in real_files() if f.stem.startswith(("cura-4.11", "prusaslicer"))]


@pytest.mark.parametrize("src, method", CASES, ids=lambda c: getattr(c, "stem", c))
def test_default_never_faster_than_sliced(src, method, tmp_path):
    """Every motion line we write runs at a modal F at most its original move's F (mm/min,
    to the writer's 0.1 of rounding), first layer included; what the firmware does with it
    can only be slower."""
    data = b"".join(src.read_bytes().splitlines(keepends=True)[:HEAD_LINES])
    cut = tmp_path / src.name
    cut.write_bytes(data)
    opts = Options(method=method)
    assert opts.speed == "slicer"
    program = read_for(cut, PROFILE)
    fw = firmware.move_limits(program, PROFILE)
    path = path_for(program, PROFILE, fw)
    sched = plan(path, PROFILE, PlanRequest.from_options(PROFILE, opts), fw)
    # the plan itself: no sample interval faster than the F of the segments it spans
    ka, kb = path.segment_at(sched.s_mm[:-1]), path.segment_at(sched.s_mm[1:])
    f = path.feed_mm_s
    top = np.maximum(f[ka], f[kb])
    for i in np.flatnonzero(kb - ka > 1):  # an interval across a short segment
        top[i] = f[ka[i]:kb[i] + 1].max()
    v = np.diff(sched.s_mm) / sched.ts_s
    assert np.all(v <= top * (1 + 1e-6) + 1e-6)
    res = write(program, path, sched, PROFILE, accel_mm_s2=writer_accel(path, PROFILE, fw, None),
                cells=sched.cells,
                feed_cap_mm_s=planning_path(path, opts.speed, PROFILE).feed_mm_s,
                settings=firmware.accel_settings(program, PROFILE,
                                                 firmware.accel_clamp(program, PROFILE,
                                                                      {"x": 3000.0, "y": 3000.0,
                                                                       "z": 100.0})))
    lines = res.data.splitlines()
    modal = None
    checked = 0
    for line, (tag, mi) in zip(lines, res.tags):
        f = _f_word(line) if line[:2] in (b"G0", b"G1", b"G2", b"G3") or line[:1] == b"G" else None
        if f is not None:
            modal = f
        if tag == T_NEW and line[:1] == b"G":
            sliced = program.moves[mi].feed_mm_s * 60.0
            assert modal is not None and modal <= sliced + 0.1, (line, sliced)
            checked += 1
    assert checked > 0.5 * len(program.moves) or checked > 100


def test_feed_ceiling_closed_forms():
    text = ("G90\nM82\nG92 E0\nG1 Z0.2 F600\nG1 X10 Y0 E1 F1200\nG1 X20 Y0 F6000\n"
            "G1 Z0.4 F600\nG1 X30 Y0 E2 F3000\nG1 X40 Y0 E2.5 F3000\nG0 X0 Y0 F9000\n")
    path = build_path(read_program(text.encode(), "t"))
    feed = path.feed_mm_s
    assert np.array_equal(feed_ceiling(path, "slicer"), feed)
    cap = feed_ceiling(path, "machine", machine_vmax_mm_s=70.0)
    first = path.layer == 0
    assert first.any() and (~first).any()
    assert np.array_equal(cap[first], feed[first])
    # V_max, or the sliced F where that is higher (the 150 mm/s travel)
    assert np.array_equal(cap[~first], np.maximum(feed[~first], 70.0))
    assert feed[~first].max() == 150.0
    # volumetric: v ≤ Q / (A · dE/L); the 10 mm move with 1 mm of filament at Q = 5 mm³/s
    q, d = 5.0, 1.75
    cap = feed_ceiling(path, "machine", max_volumetric_mm3_s=q, filament_diameter_mm=d)
    assert np.all(np.isinf(cap[(~first) & (path.de_mm <= 0)]))  # no V_max given: none
    area = math.pi * (d / 2) ** 2
    k = int(np.flatnonzero((~first) & (path.de_mm > 0))[0])
    assert cap[k] == pytest.approx(q / (area * path.de_mm[k] / path.length_mm[k]))
    travel = (~first) & (path.de_mm <= 0)
    assert np.all(np.isinf(cap[travel]))


def test_slicer_policy_is_not_capped_by_the_profile_vmax():
    """ender3pro's V_max (70 mm/s, the paper's test) must not cap Cura's 150 mm/s travels under
    the default: that made the output slower than the input."""
    assert PROFILE.limits.vmax_mm_s == 70.0
    assert plan_vmax(PROFILE, "slicer", None) == 500.0
    assert plan_vmax(PROFILE, "machine", None) == 500.0  # V_max is in the ceiling instead
    assert plan_vmax(PROFILE, "slicer", 40.0) == 40.0


def _run_cli(tmp_path, src, *args):
    out = tmp_path / f"out{len(list(tmp_path.iterdir()))}.gcode"
    rep = tmp_path / f"r{len(list(tmp_path.iterdir()))}.json"
    r = CliRunner().invoke(cli, [str(src), "-o", str(out), "-m", "ender3pro", "--method",
                                 "kinematic", "--report", str(rep), *args])
    assert r.exit_code == 0, r.output
    import json

    return out.read_bytes(), json.loads(rep.read_text()), r.output


def test_cli_policies(tmp_path):
    src = tmp_path / "cura.gcode"
    src.write_bytes(b"".join((REAL / "cura-4.11_ender3_3dbenchy.gcode").read_bytes()
                             .splitlines(keepends=True)[:HEAD_LINES]))
    d_slicer, r_slicer, msg = _run_cli(tmp_path, src)
    assert r_slicer["speed"] == "slicer" and "speed slicer" in msg
    d_alias, r_alias, _ = _run_cli(tmp_path, src, "--use-slicer-feed")
    assert d_alias == d_slicer and r_alias["speed"] == "slicer"
    d_machine, r_machine, msg = _run_cli(tmp_path, src, "--speed", "machine")
    assert r_machine["speed"] == "machine" and "speed machine" in msg
    # both faster than the file as sliced (a stock printer's 500 mm/s² vs the plan's 3000);
    # the machine's speeds faster still
    assert r_machine["output_time_s"] < r_slicer["output_time_s"] < r_slicer["input_time_s"]
    # the first layer keeps its sliced speeds under machine too
    prog_in = read_program(src.read_bytes(), "in")
    first_z = min(mv.end_mm[2] for mv in prog_in.moves if mv.e_end_mm > mv.e_start_mm)
    out = read_program(d_machine, "out")
    fast_first = [mv for mv in out.moves
                  if mv.e_end_mm > mv.e_start_mm and abs(mv.end_mm[2] - first_z) < 1e-6
                  and mv.feed_mm_s > max(m.feed_mm_s for m in prog_in.moves
                                         if m.e_end_mm > m.e_start_mm and abs(m.end_mm[2] - first_z) < 1e-6) + 1e-3]
    assert fast_first == []
