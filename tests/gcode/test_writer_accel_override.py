"""The plan's accelerations over the file's own (``--accel plan``, the default; issue 20).

Files that set their own, lower accelerations (PrusaSlicer's ``M204 P800`` / ``P1000`` per
feature, Cura's Klipper ``SET_VELOCITY_LIMIT ACCEL=500``) run at the plan's: the written file
keeps every line of the original and adds, right after each line that lowers an acceleration
below the plan's (after the homing that follows it, if any), one line setting the plan's again;
after the last move it gives the file's own back. ``--accel file`` is the behaviour before:
its output is byte for byte what it was (hashes recorded on main 69fb6c5, ident line left out).
"""

from __future__ import annotations

import hashlib

import pytest

from gcode_feedopt import firmware
from gcode_feedopt.gcode.reader import read_program
from gcode_feedopt.pipeline import Options, optimize_file
from gcode_feedopt.profile import load_profile
from gcode_feedopt.vm.firmware import estimate_time_s

from ..conftest import GCODE_DIR
from ..firmware import reference

pytestmark = pytest.mark.shared_data

#: the first 8,000 lines: the MINI's start block (M201/M204 before G28/G29) and 5,585 moves
#: with 98 of its per-feature M204 lines
HEAD = 8000
OURS = b"; gcode-feedopt: the plan's acceleration (--accel plan)"
BACK = b"; gcode-feedopt: the file's own acceleration again"
OURS_J = b"; gcode-feedopt: the plan's junctions (--accel plan)"
BACK_J = b"; gcode-feedopt: the file's own junctions again"
MOTION = (b"G0 ", b"G1 ", b"G2 ", b"G3 ")

#: sha256 of the output without its ident line (line 2), kinematic, default speeds, made by
#: main 69fb6c5 (before --accel): ``--accel file`` must give the same bytes. The MINI's since
#: its classic-jerk segments are one line at the plan's cap instead of a staircase of sampled
#: speeds (pieces.plan_peaks; before d333411b…, which ran slower than planned; now as
#: planned, 242.91 s)
FILE_POLICY_SHA = {
    ("prusaslicer-2.6.1_mini_3dbenchy", "ender3pro"):
        "8074adc08495fabb3280a7d290e9516216ab584756521b31a6cc24aa40beaad7",
    ("cura-4.8_ender3_square-tower", "ender3pro"):
        "92b198dd0000d2714f235bf41e8832d06c37a74dcafc2f6cb17a0ce9f4661caf",
    ("cura-4.8_ender3_square-tower", "voron24"):
        "1af0d424191a4333ff3fec7f0be06c33c40d106090df0abb832b882657bf43f2",
}


def head(name: str) -> bytes:
    return b"".join((GCODE_DIR / f"{name}.gcode").read_bytes().splitlines(True)[:HEAD])


def run(tmp_path, name: str, machine: str, **opts):
    src = tmp_path / "in.gcode"
    src.write_bytes(head(name))
    out = tmp_path / "out.gcode"
    profile = load_profile(machine)
    rep = optimize_file(src, out, profile, Options(method="kinematic", allow_slower=True, **opts))
    return rep, src.read_bytes(), out.read_bytes(), profile


def untouched(lines):
    """The lines of a file no run re-writes: not motion, not time metadata, not ours."""
    return [ln for ln in lines if not ln.startswith(MOTION) and not ln.startswith(b"M73 ")
            and b"gcode-feedopt" not in ln and b"estimated printing time" not in ln
            and not ln.startswith((b";TIME:", b";TIME_ELAPSED:"))]


def check_common(rep, src: bytes, data: bytes, profile):
    """What every default run must do: every original line kept, the time split exact, the
    firmware model started as configured runs the written file in the plan's time."""
    # every original line in order; the others ours (the clamp's ``M201 X Y Z`` has no comment)
    got, want = untouched(data.splitlines()), untouched(src.splitlines())
    k = 0
    for ln in got:
        if k < len(want) and ln == want[k]:
            k += 1
        else:
            assert ln.startswith((b"M201 ", b"M204 ", b"M205 ", b"SET_VELOCITY_LIMIT ")), ln
    assert k == len(want)
    sp = rep.extra["time_split_s"]
    assert sum(sp.values()) == pytest.approx(rep.output_time_s - rep.input_time_s, abs=1e-6)
    # the file's own accelerations overridden count under ``limits``, its junction settings
    # (and the firmware's) under ``junctions``
    ex = rep.extra
    assert sp["limits"] == pytest.approx(ex["input_time_plan_accel_own_junctions_s"]
                                         - rep.input_time_s)
    assert sp["junctions"] == pytest.approx(ex["input_time_plan_accel_s"]
                                            - ex["input_time_plan_accel_own_junctions_s"])
    out = read_program(data, "out")
    t_out = estimate_time_s(out, firmware.as_configured(profile))
    assert t_out == pytest.approx(rep.output_time_s, rel=1e-9)
    return out


def test_prusaslicer_mini_benchy(tmp_path):
    name = "prusaslicer-2.6.1_mini_3dbenchy"
    rep, src, data, profile = run(tmp_path, name, "ender3pro")
    out = check_common(rep, src, data, profile)
    assert rep.accel == "plan" and "accel plan" in rep.summary()
    # measured: 236.6 s -> 215.9 s (-8.8 %); --accel file made it slower (244.0 s, kept)
    assert rep.output_time_s < 0.92 * rep.input_time_s
    # the firmware runs it as planned: a segment with a classic-jerk junction (M205 X8 Y8) is
    # one line at the plan's cap (pieces.plan_peaks); as a staircase of sampled speeds it ran
    # 1.0 % slower
    assert rep.output_time_s == pytest.approx(rep.plan_time_s, rel=1e-4)
    # the lines we added: exactly one after each line lowering an acceleration before the
    # last move, the start block's after G29 (homing and probing run at the file's values)
    lines = data.splitlines()
    src_lines = src.splitlines()
    last_move = max(k for k, ln in enumerate(src_lines) if ln.startswith(MOTION))
    expect = []
    for k, ln in enumerate(src_lines[:last_move]):
        if ln.startswith(b"G29"):
            expect += [(ln, b"M204 P3000 T3000"), (ln, b"M201 X3000 Y3000")]
        elif ln.startswith((b"M204 P800", b"M204 P1000")):
            expect.append((ln, b"M204 P3000"))
        elif ln.startswith(b"M204 T2500"):
            expect.append((ln, b"M204 T3000"))
    got = []
    for k, ln in enumerate(lines):
        if ln.endswith(OURS):
            j = k - 1
            while lines[j].endswith(OURS):
                j -= 1
            got.append((lines[j], ln[:-len(OURS)].rstrip()))
    assert got == expect
    # its classic jerk (M205 X8 Y8) gives way to the hardware's speed step (ender3pro: 20)
    # (after the G29 that follows it, before the first move)
    mine = [k for k, ln in enumerate(lines) if ln.endswith(OURS_J)]
    assert [lines[k] for k in mine] == [b"M205 X20 Y20 " + OURS_J]
    g29 = next(k for k, ln in enumerate(lines) if ln.startswith(b"G29"))
    jerk = next(k for k, ln in enumerate(lines) if ln.startswith(b"M205 X8"))
    first = next(k for k, ln in enumerate(lines) if ln.startswith(MOTION) and k > g29)
    assert jerk < g29 < mine[0] < first
    assert [ln[:-len(BACK)].rstrip() for ln in lines if ln.endswith(BACK)] == [
        b"M204 P1000 T2500", b"M201 X2500 Y2500"]
    assert [ln[:-len(BACK_J)].rstrip() for ln in lines if ln.endswith(BACK_J)] == [
        b"M205 X8 Y8"]
    assert len(got) == rep.extra["accel_override_lines"] - 4
    assert rep.extra["time_split_s"]["junctions"] < -0.005 * rep.input_time_s
    # the firmware model reading the raw lines arrives at the plan's values on every move
    # from the first to the last (jerk: 20, the kinematic plan slows no stretch); retraction
    # and Z stay the file's
    lim = firmware.move_limits(out, firmware.as_configured(profile))
    moving = slice(next(i for i, mv in enumerate(out.moves) if mv.line_no > 300), None)
    assert set(lim.accel_mm_s2[moving].tolist()) == {3000.0}
    assert set(lim.max_accel_mm_s2[moving, 0].tolist()) == {3000.0}
    assert set(lim.e_accel_mm_s2[moving].tolist()) == {1250.0}
    assert set(lim.jerk_mm_s[moving, 0].tolist()) == {20.0}
    # after the file the printer is as its owner configured it (ender3pro: 500)
    snaps = firmware.Replay(out, profile).snaps
    assert (snaps[-1].accel_print, snaps[-1].max_accel["x"]) == (500.0, 500.0)


def one_override(data: bytes, ours: bytes, back: bytes):
    """The square tower's written lines and the index of its one lowering line
    (``SET_VELOCITY_LIMIT ... ACCEL=500``), asserting ``ours`` right after it, no other line of
    ours, and ``back`` as the one line giving the file's value back."""
    lines = data.splitlines()
    k = lines.index(b"SET_VELOCITY_LIMIT SQUARE_CORNER_VELOCITY=1 ACCEL=500")
    assert lines[k + 1] == ours + OURS
    assert [ln for ln in lines if ln.endswith(OURS)] == [lines[k + 1]]
    assert [ln for ln in lines if ln.endswith(BACK)] == [back + BACK]
    return lines, k


def test_square_tower_on_marlin(tmp_path):
    """Cura's ``SET_VELOCITY_LIMIT SQUARE_CORNER_VELOCITY=1 ACCEL=500``: the Marlin model reads
    its ACCEL as M204 P and T, so ``M204 P3000 T3000`` follows it."""
    rep, src, data, profile = run(tmp_path, "cura-4.8_ender3_square-tower", "ender3pro")
    check_common(rep, src, data, profile)
    # measured: 1335.9 s -> 886.5 s (-33.6 %); --accel file: 1325.2 s (-0.8 %)
    assert rep.output_time_s < 0.7 * rep.input_time_s
    assert rep.output_time_s == pytest.approx(rep.plan_time_s, rel=0.005)
    one_override(data, b"M204 P3000 T3000 ", b"M204 P500 T500 ")
    # a pressure-advance tower calibrates at the accelerations it was sliced with: said
    assert any("TUNING_TOWER" in n and "--accel file" in n and ":13:" in n for n in rep.notes), rep.notes
    rep_f, *_ = run(tmp_path, "cura-4.8_ender3_square-tower", "ender3pro", accel="file")
    assert not any("TUNING_TOWER" in n for n in rep_f.notes)


def test_klipper_set_velocity_limit(tmp_path):
    """voron24 (Klipper, plan 5000 mm/s², configured 3000): the file's ACCEL=500 is followed by
    ``SET_VELOCITY_LIMIT ACCEL=5000``; square_corner_velocity stays the file's 1 mm/s."""
    rep, src, data, profile = run(tmp_path, "cura-4.8_ender3_square-tower", "voron24")
    out = check_common(rep, src, data, profile)
    # measured: 1474.4 s -> 874.2 s (-40.7 %); --accel file: 1474.4 s
    assert rep.output_time_s < 0.65 * rep.input_time_s
    assert rep.output_time_s == pytest.approx(rep.plan_time_s, rel=0.005)
    lines, k = one_override(data, b"SET_VELOCITY_LIMIT ACCEL=5000 ",
                            b"SET_VELOCITY_LIMIT ACCEL=500 ")
    lim = firmware.move_limits(out, firmware.as_configured(profile))
    moving = slice(next(i for i, mv in enumerate(out.moves) if mv.line_no > k + 1), -1)
    assert set(lim.accel_mm_s2[moving].tolist()) == {5000.0}
    replay = firmware.Replay(out, profile)
    snaps, si = replay.snaps, replay.si
    assert snaps[si[-1]].scv == 1.0


def test_klipper_runs_the_twins_plan_as_planned(tmp_path):
    """pidd on voron24 (Klipper, minimum_cruise_ratio 0.5): the firmware model started as
    configured runs the written file in the plan's time, as on Marlin. The slow-down planned
    with Marlin's look-ahead, faster than Klipper runs a chain of short moves: the tower's
    head then ran 0.46 % slower than planned (871.5 s planned, 875.5 s run), and the twin
    slowed stretches whose violations came from that faster plan."""
    src = tmp_path / "in.gcode"
    src.write_bytes(head("cura-4.8_ender3_square-tower"))
    profile = load_profile("voron24")
    rep = optimize_file(src, tmp_path / "out.gcode", profile, Options(method="pidd"))
    assert rep.output_time_s == pytest.approx(rep.plan_time_s, rel=1e-3)
    assert rep.output_time_s <= rep.extra["input_time_plan_accel_s"] * (1 + 1e-3)


def test_klipper_refuses_m204_p_alone():
    """Klipper refuses ``M204 P800`` alone: nothing lowers there, no line is added; the start
    block's ``M204 P1250 R1250 T2500`` (Klipper: 1250) is raised after G29."""
    profile = load_profile("voron24")
    prog = read_program(head("prusaslicer-2.6.1_mini_3dbenchy"), "mini")
    ov = firmware.accel_override(prog, profile)
    assert [prog.lines[k].split()[0] for k in ov.lines] == [b"G29"]
    assert ov.lines[next(iter(ov.lines))] == ["SET_VELOCITY_LIMIT ACCEL=5000"]
    assert ov.restore == {"accel_print": 1250.0, "accel_travel": 1250.0}


def test_the_reference_replay_agrees():
    """The fast and the reference replays apply the override alike (bit for bit)."""
    profile = load_profile("ender3pro")
    prog = read_program(head("prusaslicer-2.6.1_mini_3dbenchy"), "mini")
    ov = firmware.accel_override(prog, profile)
    a = firmware.move_limits(prog, profile, override=ov)
    b = reference.move_limits(prog, profile, override=ov)
    for f in ("accel_mm_s2", "max_accel_mm_s2", "e_accel_mm_s2", "jerk_mm_s"):
        assert (getattr(a, f) == getattr(b, f))[~__import__("numpy").isnan(getattr(a, f))].all()
    assert (estimate_time_s(prog, profile, override=ov)
            == reference.estimate_time_s(prog, profile, override=ov))
    assert firmware.accel_override(prog, profile, "file") is None


@pytest.mark.parametrize("name, machine", sorted(FILE_POLICY_SHA))
def test_file_policy_is_the_old_output(tmp_path, name, machine):
    rep, _, data, _ = run(tmp_path, name, machine, accel="file")
    assert rep.extra["accel_override_lines"] == 0 and "accel file" in rep.summary()
    lines = data.splitlines(True)
    assert b"accel" not in lines[1]  # the ident line as before: no word is ``file``
    assert hashlib.sha256(b"".join(lines[:1] + lines[2:])).hexdigest() == \
        FILE_POLICY_SHA[(name, machine)]


def test_cli_and_batch_take_the_policy(tmp_path):
    """``--accel`` on optimize and batch, ``plan`` by default in both; batch makes again an
    output made under the other policy (the ident line records ``accel plan``)."""
    import shutil

    from click.testing import CliRunner

    from gcode_feedopt.cli import cli

    jobs = tmp_path / "jobs"
    jobs.mkdir()
    (jobs / "tower.gcode").write_bytes(b"".join(
        (GCODE_DIR / "cura-4.8_ender3_square-tower.gcode").read_bytes()
        .splitlines(True)[:2000]))
    out = tmp_path / "out"

    def batch(*extra):
        r = CliRunner().invoke(cli, ["batch", str(jobs), "-o", str(out), "-j", "1", "--machine",
                                     "ender3pro", "--method", "kinematic", *extra])
        assert r.exit_code == 0, r.output
        return r.output.splitlines()[1], (out / "tower.gcode").read_bytes()

    row, data = batch()
    assert row.rstrip().endswith("ok") and b"mode refeed, accel plan]" in data[:4096]
    assert b"M204 P3000 T3000 " + OURS in data
    assert "skipped" in batch()[0]
    row, data = batch("--accel", "file")
    assert row.rstrip().endswith("ok") and OURS not in data and b"accel" not in data[:4096]
    one = tmp_path / "one.gcode"
    shutil.copy(jobs / "tower.gcode", tmp_path / "in.gcode")
    r = CliRunner().invoke(cli, [str(tmp_path / "in.gcode"), "-o", str(one), "--machine",
                                 "ender3pro", "--method", "kinematic"])
    assert r.exit_code == 0, r.output
    assert "accel plan (the plan's accelerations and junctions over the file's)" in r.output
    assert b"M204 P3000 T3000 " + OURS in one.read_bytes()
    r = CliRunner().invoke(cli, [str(tmp_path / "in.gcode"), "-o", str(one), "--machine",
                                 "ender3pro", "--accel", "fast"])
    assert r.exit_code == 2 and "'fast' is not one of 'plan', 'file'" in r.output


def test_the_twin_keeps_the_tolerance_at_the_plans_accelerations(tmp_path):
    """pidd (the default method) on the MINI Benchy's first 8,000 lines: the predicted and the
    executed contour error (firmware model + nominal plant) within 0.1 mm at η 0.95."""
    src = tmp_path / "in.gcode"
    src.write_bytes(head("prusaslicer-2.6.1_mini_3dbenchy"))
    profile = load_profile("ender3pro")
    rep = optimize_file(src, tmp_path / "out.gcode", profile, Options())
    # measured: 236.6 s -> 217.4 s (-8.1 %), plan 215.8 s; executed worst 0.097 mm, 100 % within
    assert rep.output_time_s < 0.93 * rep.input_time_s
    # every sample within its bound or carried by the stringency's budget (optimize.slowdown.budget)
    assert rep.extra["relaxed_samples"] == 0
    assert rep.predicted_within_fraction >= rep.stringency
    ex = rep.extra["executed"]
    assert ex["within_fraction"] >= rep.stringency
    assert ex["time_s"] == pytest.approx(rep.plan_time_s, rel=0.015)
    # 97 lines after the file's M204 lines and 2 after its G29 (99), 1 after its M205 X8 Y8
    # (the hardware's jerk), and the restores of its own M204, M201 and M205 after the last
    # move
    assert rep.extra["accel_override_lines"] == 103


def test_which_lines_lower_and_what_we_write():
    """Marlin ``M204 S`` sets P and T; only what a line sets below the plan's is re-set;
    a lowering before homing gets our line after the homing; none after the last move."""
    profile = load_profile("ender3pro")  # plan: P 3000, T 3000, M201 X/Y 3000
    text = "\n".join([
        "M204 S500", "G28", "M204 P1000 T5000", "M201 X4000 Y2000 Z50", "G1 X10 Y10 F3000",
        "M204 S4000 P2000", "G1 X20 Y10 E1 F1200", "SET_VELOCITY_LIMIT ACCEL=800",
        "G1 X20 Y20 E2", "M204 P500", "M84", ""]).encode()
    prog = read_program(text, "t")
    ov = firmware.accel_override(prog, profile)
    assert {prog.lines[k].strip(): v for k, v in ov.lines.items()} == {
        b"G28": ["M204 P3000 T3000"], b"M204 P1000 T5000": ["M204 P3000"],
        b"M201 X4000 Y2000 Z50": ["M201 Y3000"], b"M204 S4000 P2000": ["M204 P3000"],
        b"SET_VELOCITY_LIMIT ACCEL=800": ["M204 P3000 T3000"]}
    # at the last move the file has P and T 800 (SET_VELOCITY_LIMIT), Y 2000
    assert ov.restore == {"accel_print": 800.0, "accel_travel": 800.0, "y": 2000.0}
    lim = firmware.move_limits(prog, profile, override=ov)
    # a higher value of the file's stays (T 5000 on the travel: M201 and the clamp cap it)
    assert lim.accel_mm_s2.tolist() == [5000.0, 3000.0, 3000.0]
    assert lim.max_accel_mm_s2[:, :2].tolist() == [[4000.0, 3000.0]] * 3
