"""The main command end to end through click: report keys, dry run, in place, second run,
sampled mode, trajectory CSV, unavailable methods. Uses the small bundled butterfly."""

from __future__ import annotations

import json
import pathlib
import shutil

import numpy as np
import pytest
from click.testing import CliRunner

from gcode_feedopt.cli import cli

REPO = pathlib.Path(__file__).resolve().parents[1]
SAMPLE = REPO / "sample_gcode" / "butterfly.gcode"


@pytest.fixture()
def src(tmp_path):
    p = tmp_path / "in.gcode"
    shutil.copyfile(SAMPLE, p)
    return p


def _run(args):
    return CliRunner().invoke(cli, [str(a) for a in args])


def test_report_has_the_promised_keys_and_output_is_not_slower(src, tmp_path):
    out, rep = tmp_path / "out.gcode", tmp_path / "r.json"
    res = _run([src, "-o", out, "--machine", "ender3pro", "--report", rep, "-q"])
    assert res.exit_code == 0, res.output
    d = json.loads(rep.read_text())
    for key in ("input_time_s", "output_time_s", "moves", "method", "tolerance_mm", "stringency",
                "moves_changed", "lines_written", "time_source"):
        assert key in d, key
    assert d["method"] == "pidd"  # the default: the digital twin keeps the tolerance
    # every sample within its bound or carried by the stringency's budget (optimize.slowdown.budget)
    assert d["extra"]["relaxed_samples"] == 0
    assert d["extra"]["rest_uncertainty_mm"] > 0  # zσ at rest: the note's cause (pipeline)
    assert d["predicted_within_fraction"] >= d["stringency"]
    assert not any(n.startswith("the twin expects only") for n in d["notes"])
    assert d["extra"]["optimizer"] == "slowdown"
    assert d["moves"] > 1000
    assert d["output_time_s"] <= d["input_time_s"] * 1.001
    assert src.read_bytes() == SAMPLE.read_bytes()
    assert b"; processed by gcode-feedopt" in out.read_bytes()


def test_dry_run_writes_nothing(src, tmp_path):
    before = (src.read_bytes(), src.stat().st_mtime_ns)
    res = _run([src, "--machine", "ender3pro", "--dry-run", "-q"])
    assert res.exit_code == 0, res.output
    assert (src.read_bytes(), src.stat().st_mtime_ns) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.gcode"]


def test_in_place_then_second_run_refused_then_forced(src):
    res = _run(["--machine", "ender3pro", src])  # PrusaSlicer passes the path last
    assert res.exit_code == 0, res.output
    once = src.read_bytes()
    assert once != SAMPLE.read_bytes()
    res = _run(["--machine", "ender3pro", src])
    assert res.exit_code != 0
    assert "already processed" in res.output and "--force" in res.output
    assert src.read_bytes() == once
    res = _run(["--machine", "ender3pro", "--force", "-q", src])
    assert res.exit_code == 0, res.output
    # the first pass's ident line is kept byte for byte; the forced pass adds its own
    assert src.read_bytes().count(b"; processed by gcode-feedopt") == 2


def test_sampled_mode_states_ts_and_trajectory_csv_rows_per_ts(src, tmp_path):
    out, csv = tmp_path / "s.gcode", tmp_path / "t.csv"
    # --allow-slower: one G1 per 2 ms at the butterfly's sliced speeds runs slower than the
    # file (the firmware's line budget), which is the point here
    res = _run([src, "-o", out, "--machine", "ender3pro", "--mode", "sampled",
                "--trajectory", csv, "-q", "--allow-slower"])
    assert res.exit_code == 0, res.output
    assert b"Ts = 2 ms" in out.read_bytes()
    text = csv.read_text().splitlines()
    assert text[0] == "t,x,y,z,e"
    t = np.loadtxt(csv, delimiter=",", skiprows=1)[:, 0]
    assert np.allclose(np.diff(t), 0.002, atol=1e-6)


@pytest.mark.parametrize("machine,warned", [("ender3pro", True), ("voron24", False)])
def test_sampled_mode_above_the_line_budget_says_so(src, tmp_path, machine, warned):
    """500 lines/s against ender3pro's serial budget of 300 is stated; voron24 (Klipper's
    host queue, 2000) is within."""
    rep = tmp_path / "r.json"
    res = _run([src, "-o", tmp_path / "s.gcode", "--machine", machine, "--mode", "sampled",
                "--method", "kinematic", "--allow-slower", "--report", rep])
    assert res.exit_code == 0, res.output
    notes = " ".join(json.loads(rep.read_text())["notes"])
    assert ("max_lines_per_s" in notes) == warned, notes


@pytest.mark.parametrize("method", ["conservative", "pb", "pidd", "oracle"])
def test_twin_methods_write_verified_output(src, tmp_path, method):
    before = src.read_bytes()
    rep = tmp_path / "r.json"
    res = _run([src, "-o", tmp_path / "o.gcode", "--machine", "ender3pro", "--method", method,
                "--report", rep])
    assert res.exit_code == 0, res.output
    assert json.loads(rep.read_text())["method"] == method
    assert src.read_bytes() == before


def test_dd_offline_is_refused_with_the_alternative(src):
    res = _run([src, "--machine", "ender3pro", "--method", "dd"])
    assert res.exit_code == 2 and "use --method pidd" in res.output


def test_unreachable_tolerance_fails_in_one_line_and_leaves_the_input(src):
    before = src.read_bytes()
    res = _run([src, "--machine", "ender3pro", "--method", "pidd", "--tolerance", "0.005"])
    assert res.exit_code == 2
    assert "--tolerance above" in res.output and len(res.output.strip().splitlines()) == 1
    assert src.read_bytes() == before


def test_vmax_override_slows_the_output(src, tmp_path):
    reps = []
    for extra in ([], ["--vmax", "20"]):
        rep = tmp_path / f"r{len(reps)}.json"
        res = _run([src, "-o", tmp_path / "o.gcode", "--machine", "ender3pro", "--report", rep,
                    "-q", "--allow-slower", *extra])
        assert res.exit_code == 0, res.output
        reps.append(json.loads(rep.read_text()))
    assert reps[1]["output_time_s"] > reps[0]["output_time_s"] * 1.05


def test_slower_output_is_not_written_unless_asked(tmp_path):
    """issue 18: the PrusaSlicer part at its sliced speeds, its own accelerations and its own
    junctions (--accel file; under the default its classic jerk 8 mm/s gives way to the
    hardware's 20 and the output is 0.1 % faster): the twin slows some stretches to keep the
    tolerance, so our output would run slower than the file. By default the input stays as
    it was (in place) or goes to -o unchanged, the summary says why; --allow-slower writes
    it; batch reports it as kept."""
    src = REPO / "sample_gcode" / "part_prusaslicer.gcode"
    before = src.read_bytes()
    work = tmp_path / "part.gcode"
    work.write_bytes(before)
    r = CliRunner().invoke(cli, ["--machine", "ender3pro", str(work), "--accel", "file",
                                 "--report", str(tmp_path / "r.json")])
    assert r.exit_code == 0, r.output
    assert work.read_bytes() == before
    assert "kept the input as it was" in r.output and "--allow-slower" in r.output
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["output_time_s"] == rep["input_time_s"] and rep["moves_changed"] == 0
    assert rep["extra"]["kept_input"]["plan_output_time_s"] > rep["input_time_s"]
    out = tmp_path / "o.gcode"
    r = CliRunner().invoke(cli, [str(work), "-o", str(out), "-m", "ender3pro", "--accel", "file"])
    assert r.exit_code == 0 and out.read_bytes() == before
    r = CliRunner().invoke(cli, [str(work), "-o", str(out), "-m", "ender3pro", "--accel", "file",
                                 "--allow-slower"])
    assert r.exit_code == 0 and b"; processed by gcode-feedopt" in out.read_bytes()[:4096]
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    (jobs / "part.gcode").write_bytes(before)
    r = CliRunner().invoke(cli, ["batch", str(jobs), "-m", "ender3pro", "-j", "1", "--accel",
                                 "file"])
    assert r.exit_code == 0, r.output
    assert "kept" in r.output and (jobs / "part.gcode").read_bytes() == before


def test_progress_on_a_terminal_only_and_output_unchanged(tmp_path):
    """Issue 18: a long run is not silent on a terminal; a pipe (print hosts, logs) gets the
    summary only; the G-code is the same either way."""
    import os
    import pty
    import subprocess
    import sys

    def run(out, tty):
        cmd = [sys.executable, "-m", "gcode_feedopt", str(SAMPLE), "-o", str(out),
               "--machine", "ender3pro", "--method", "kinematic"]
        if not tty:
            r = subprocess.run(cmd, capture_output=True)
            assert r.returncode == 0, r.stderr
            return r.stderr
        master, slave = pty.openpty()
        p = subprocess.Popen(cmd, stderr=slave, stdout=subprocess.DEVNULL)
        os.close(slave)
        buf = b""
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:
                break
            if not chunk:
                break
            buf += chunk
        assert p.wait() == 0, buf
        os.close(master)
        return buf

    a, b = tmp_path / "tty.gcode", tmp_path / "pipe.gcode"
    on_tty, on_pipe = run(a, True), run(b, False)
    assert b"planning" in on_tty and b"reading" in on_tty
    assert b"planning" not in on_pipe and b"\r" not in on_pipe
    assert a.read_bytes() == b.read_bytes()


def test_progress_ticker_never_hands_a_forked_worker_a_held_lock(monkeypatch):
    """The planner forks workers while the progress line ticks: each fork waits for the line to
    be written (the lock is taken before the fork), the parent's ticker goes on, and the child
    has a free lock and no ticker."""
    import io
    import os
    import sys

    from gcode_feedopt.cli.options import Progress

    monkeypatch.setattr(sys, "stderr", io.StringIO())
    p = Progress("x")
    try:
        p("planning")
        pid = os.fork()
        if pid == 0:  # the child: exit 0 only when the lock is free and the ticker stopped
            ok = p._lock.acquire(timeout=2.0) and p._stop.is_set()
            os._exit(0 if ok else 1)
        _, status = os.waitpid(pid, 0)
        assert os.waitstatus_to_exitcode(status) == 0
        assert p._lock.acquire(timeout=2.0)  # the parent's lock is free again
        p._lock.release()
        assert not p._stop.is_set() and p._thread.is_alive()
    finally:
        p.done()
    assert "planning" in sys.stderr.getvalue()


def _shaped_profile(tmp_path):
    """voron24 printing through Klipper's MZV at its 45.6 Hz modes."""
    import dataclasses

    from gcode_feedopt.firmware.shaper import Shaper
    from gcode_feedopt.profile import load_profile, save_profile
    p = load_profile("voron24")
    sh = {a: Shaper("mzv", 45.6, 0.1, True) for a in "xy"}
    p = dataclasses.replace(p, name="voron24_shaped",
                            firmware=dataclasses.replace(p.firmware, input_shaper=sh))
    (tmp_path / "prof").mkdir()
    return save_profile(p, tmp_path / "prof" / "voron24_shaped.yaml")


def test_a_file_that_sets_the_input_shaper_is_told_which_the_plan_assumed(src, tmp_path):
    lines = src.read_text().splitlines(keepends=True)
    lines.insert(5, "SET_INPUT_SHAPER SHAPER_FREQ_X=45.6 SHAPER_FREQ_Y=45.6\n")
    src.write_text("".join(lines))
    res = _run([src, "-o", tmp_path / "out.gcode", "--machine", _shaped_profile(tmp_path)])
    assert res.exit_code == 0, res.output
    assert (f"{src}:6: the file sets the input shaper (SET_INPUT_SHAPER SHAPER_FREQ_X=45.6 "
            "SHAPER_FREQ_Y=45.6); the twin planned with voron24_shaped's (x mzv 45.6 Hz") in res.output
    assert "SET_INPUT_SHAPER SHAPER_FREQ_X=45.6 SHAPER_FREQ_Y=45.6\n" in (tmp_path / "out.gcode").read_text()


def test_the_window_optimizer_refuses_a_shaped_profile_in_one_line(src, tmp_path):
    before = src.read_bytes()
    res = _run(["compare", src, "--machine", _shaped_profile(tmp_path), "--methods", "pidd"])
    assert res.exit_code == 2, res.output
    assert "does not model the firmware's input shaper" in res.output
    assert len(res.output.strip().splitlines()) == 1 and src.read_bytes() == before


def test_a_plan_the_twin_expects_to_fall_short_of_the_stringency_says_so():
    """The slow-down gives up samples it cannot bring within at any speed it may choose and
    runs them at the firmware's speed (optimize.slowdown); the budget of η stops at η itself.
    Seed 334 of tests/foreign (a servo measured with 2.7 % noise from 1 Hz) planned with a
    member whose pole sat at 0.18 Hz: 2,692 samples given up, 31.9 % expected within at η 0.95,
    223 µm RMS γ on the machine, and nothing in the summary but the share. Now the report
    names the shortfall; a rounding-sized one at the budget's edge (seen: 98.999914 % at η
    0.99, tolerance 0.029 mm on that machine's profile) is not news."""
    from types import SimpleNamespace

    from gcode_feedopt.pipeline import _short_of_stringency

    info = {"predicted_within_fraction": 0.3187365, "relaxed_samples": 2692,
            "predicted_rms_gamma_mm": 0.5707095}
    note = _short_of_stringency(info, SimpleNamespace(stringency=0.95), 0.002)
    assert note.startswith("the twin expects only 31.87 % of samples within tolerance where 95 %")
    assert "570.7 µm" in note and "2692 samples (5.4 s of motion)" in note
    assert "gcode-feedopt learn" in note
    # where they run: at the floor (the twin still expects less error there), at the
    # firmware's speed (standing still would not cure them), or both, counted
    assert "(they run at the slowest speed it may choose)" in note
    rest = _short_of_stringency(dict(info, relaxed_at_rest_samples=2692),
                                SimpleNamespace(stringency=0.95), 0.002)
    assert "(they run at the firmware's speed: standing still would not help them)" in rest
    both = _short_of_stringency(dict(info, relaxed_at_rest_samples=692),
                                SimpleNamespace(stringency=0.95), 0.002)
    assert ("(2000 run at the slowest speed it may choose, 692 at the firmware's speed, "
            "where standing still would not help)") in both
    # where the uncertainty at rest takes most of the tolerance, it is named as the cause
    # (tests/foreign seed 411 at E_max 0.02 mm: 16.4 µm of the 20 from σ_ε = 0.01 mm)
    assert "profile FRFs measured with little noise" in note  # no figures: the FRFs' advice
    tight = dict(info, rest_uncertainty_mm=0.016449, tolerance_mm=0.02)
    said = _short_of_stringency(tight, SimpleNamespace(stringency=0.95), 0.002)
    assert "16.4 µm of the 20 µm" in said and "twin.sigma_eps_mm" in said
    assert "profile FRFs measured" not in said
    loose = dict(tight, tolerance_mm=0.1)
    assert "profile FRFs measured" in _short_of_stringency(loose, SimpleNamespace(stringency=0.95),
                                                           0.002)
    edge = dict(info, predicted_within_fraction=0.98999914, relaxed_samples=685)
    assert _short_of_stringency(edge, SimpleNamespace(stringency=0.99), 0.002) is None
    short = dict(edge, predicted_within_fraction=0.985)
    assert "98.50 %" in _short_of_stringency(short, SimpleNamespace(stringency=0.99), 0.002)
    assert _short_of_stringency({}, SimpleNamespace(stringency=0.95), 0.002) is None
