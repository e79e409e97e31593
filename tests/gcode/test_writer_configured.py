"""A printer as its owner configured it runs what we planned (issue 20 point 3, in part).

``ender3pro`` is timed at 3000 mm/s² (the paper's A_max, what the frame and motors take) while
the stock firmware is configured to 500 (``firmware.configured_*``). The written file sets the
plan's limits before its first re-timed move and gives the configured ones back after its last,
so a firmware that starts from its configuration runs the written file in the planned time.
"""

import dataclasses
import pathlib

import pytest

from gcode_feedopt import firmware
from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.pipeline import Options, optimize_file
from gcode_feedopt.profile import load_profile
from gcode_feedopt.vm.firmware import estimate_time_s

REPO = pathlib.Path(__file__).resolve().parents[2]
BUTTERFLY = REPO / "sample_gcode" / "butterfly.gcode"
#: the first 20,000 lines of the Cura Benchy: at its sliced speeds the acceleration matters
CURA = b"".join((REPO.parent / "shared" / "data" / "gcode" / "cura-4.11_ender3_3dbenchy.gcode")
                .read_bytes().splitlines(keepends=True)[:20_000])
SHIPPED = load_profile("ender3pro")


def stock(profile):
    """The same machine as its firmware starts: the configured limits in force."""
    st = firmware.as_configured(profile)
    assert st.firmware.accel_mm_s2 == st.firmware.travel_accel_mm_s2 == 500.0
    assert (st.firmware.max_accel_mm_s2["x"], st.firmware.max_accel_mm_s2["y"]) == (500.0, 500.0)
    return st


def run(tmp_path, data: bytes, profile, method="kinematic", accel="plan"):
    src = tmp_path / "in.gcode"
    src.write_bytes(data)
    out = tmp_path / "out.gcode"
    rep = optimize_file(src, out, profile, Options(method=method, accel=accel))
    return rep, out.read_bytes()


def ours(data: bytes) -> list[tuple[int, bytes]]:
    return [(k, ln) for k, ln in enumerate(data.splitlines()) if b"; gcode-feedopt:" in ln]


def test_stock_printer_runs_the_plan(tmp_path):
    rep, data = run(tmp_path, CURA, SHIPPED)
    lines = ours(data)
    # the junction deviation too: the hardware's 20 mm/s speed step at 3000 mm/s² is
    # 20²/(8·3000) = 0.0167 mm, written 0.016, where the firmware runs 0.013
    assert [ln.split(b" ;")[0] for _, ln in lines] == [
        b"M201 X3000 Y3000", b"M204 P3000 R3000 T3000", b"M205 J0.016", b"M201 X500 Y500",
        b"M204 P500 R500 T500", b"M205 J0.013"]
    text = data.splitlines()
    moves = [k for k, ln in enumerate(text) if ln.startswith((b"G0 ", b"G1 "))]
    assert lines[2][0] < moves[0] and lines[3][0] == moves[-1] + 1
    # a firmware starting from its configuration runs the written file as planned ...
    out = read_program(data, "out")
    t_stock = estimate_time_s(out, stock(SHIPPED))
    assert t_stock == pytest.approx(rep.plan_time_s, rel=2e-3)
    # ... and without our lines it would not (the plan needs 3000 mm/s²)
    bare = b"".join(ln + b"\n" for ln in text if b"; gcode-feedopt:" not in ln)
    assert estimate_time_s(read_program(bare, "bare"), stock(SHIPPED)) > 1.2 * t_stock
    assert any("sets M201 X3000 Y3000 and M204 P3000 R3000 T3000 and M205 J0.016 before its "
               "first move (the plan's limits; ender3pro's firmware is configured to accel 500, "
               "max x 500, max y 500 mm/s², junction deviation 0.013 mm)" in n
               for n in rep.notes), rep.notes
    # the summary times both files as the printer is configured
    assert rep.output_time_s == pytest.approx(t_stock, rel=1e-9)
    assert rep.input_time_s == pytest.approx(
        estimate_time_s(read_program(CURA, "in"), stock(SHIPPED)))
    assert rep.extra["input_time_profile_limits_s"] < rep.input_time_s
    # after the file the printer is as its owner configured it
    snaps = firmware.Replay(out, SHIPPED).snaps
    assert snaps[-1].accel_print == snaps[-1].accel_travel == 500.0
    assert (snaps[-1].max_accel["x"], snaps[-1].max_accel["y"]) == (500.0, 500.0)
    assert snaps[-1].jd == 0.013


def test_lines_carry_what_the_file_set_before_its_first_move(tmp_path):
    """A start block that sets its own M204 before moving: the line states the model's values
    there (the file's, under ``--accel file``), not the profile's. Under ``--accel plan`` (the
    default) the file's lower values are followed by the plan's, which the line then states."""
    src = BUTTERFLY.read_bytes().replace(b"G92 E0\n", b"G92 E0\nM204 P1500 T2500\n", 1)
    rep, data = run(tmp_path, src, SHIPPED, accel="file")
    assert [ln.split(b" ;")[0] for _, ln in ours(data)][:2] == [b"M201 X3000 Y3000",
                                                                 b"M204 P1500 R3000 T2500"]
    t_stock = estimate_time_s(read_program(data, "out"), stock(SHIPPED))
    assert t_stock == pytest.approx(rep.output_time_s, rel=2e-3)
    rep, data = run(tmp_path, src, SHIPPED)
    assert [ln.split(b" ;")[0] for _, ln in ours(data)][:3] == [
        b"M204 P3000 T3000", b"M201 X3000 Y3000", b"M204 P3000 R3000 T3000"]
    t_stock = estimate_time_s(read_program(data, "out"), stock(SHIPPED))
    assert t_stock == pytest.approx(rep.output_time_s, rel=2e-3)


def test_klipper_sets_its_one_accel(tmp_path):
    kl = dataclasses.replace(SHIPPED, firmware=dataclasses.replace(
        SHIPPED.firmware, flavour="klipper", g91_relative_e=False, configured_max_accel_mm_s2=None))
    _, data = run(tmp_path, BUTTERFLY.read_bytes(), kl)
    # and the square corner velocity whose speed step is the hardware's 20 mm/s:
    # 20/√(8(√2 − 1)) = 10.99, written 10.9, where the printer runs 5
    assert [ln.split(b" ;")[0] for _, ln in ours(data)] == [
        b"SET_VELOCITY_LIMIT ACCEL=3000 SQUARE_CORNER_VELOCITY=10.9",
        b"SET_VELOCITY_LIMIT ACCEL=500 SQUARE_CORNER_VELOCITY=5"]


def test_no_lines_where_the_printer_runs_the_profile(tmp_path):
    as_profile = dataclasses.replace(SHIPPED, firmware=dataclasses.replace(
        SHIPPED.firmware, configured_accel_mm_s2=None, configured_max_accel_mm_s2=None),
        limits=dataclasses.replace(SHIPPED.limits, axis_jerk_mm_s=None))
    _, data = run(tmp_path, BUTTERFLY.read_bytes(), as_profile)
    assert ours(data) == []


def test_only_the_junction_where_the_printer_runs_the_profiles_accelerations(tmp_path):
    """The printer is configured to the plan's accelerations but to its firmware's junction
    deviation (0.013 mm), below the hardware's speed step: the junction alone is set and
    given back, and a printer starting from its configuration runs the plan."""
    as_profile = dataclasses.replace(SHIPPED, firmware=dataclasses.replace(
        SHIPPED.firmware, configured_accel_mm_s2=None, configured_max_accel_mm_s2=None))
    rep, data = run(tmp_path, BUTTERFLY.read_bytes(), as_profile)
    assert [ln.split(b" ;")[0] for _, ln in ours(data)] == [b"M205 J0.016", b"M205 J0.013"]
    assert any("sets M205 J0.016 before its first move (the plan's limits; ender3pro's firmware "
               "is configured to junction deviation 0.013 mm)" in n for n in rep.notes), rep.notes
    t_stock = estimate_time_s(read_program(data, "out"), firmware.as_configured(as_profile))
    assert t_stock == pytest.approx(rep.plan_time_s, rel=2e-3)
    assert rep.output_time_s == pytest.approx(t_stock, rel=1e-9)
