"""Batch over a folder: the shared files plus a corrupt one that fails alone."""

import os
import shutil
import signal
import subprocess
import sys
import time

from click.testing import CliRunner

from gcode_feedopt.cli import cli

from ..conftest import GCODE_DIR, REPO


def test_batch_table_and_corrupt_file_fails_alone(tmp_path):
    src = tmp_path / "jobs"
    src.mkdir()
    for name in ("cura-4.8_ender3_square-tower.gcode",):
        shutil.copy(GCODE_DIR / name, src / name)
    shutil.copy(REPO / "sample_gcode" / "butterfly.gcode", src / "butterfly.gcode")
    (src / "corrupt.gcode").write_bytes(b"GCDE\x00\x01binary")
    out = tmp_path / "out"
    r = CliRunner().invoke(cli, ["batch", str(src), "-o", str(out), "-j", "2", "--machine",
                                 "ender3pro"])
    assert r.exit_code == 1
    lines = r.output.splitlines()
    assert lines[0].split()[:5] == ["file", "before", "after", "saved", "status"]
    status = {ln.split()[0]: ln for ln in lines[1:]}
    assert "failed" in status["corrupt.gcode"] and "bgcode" in status["corrupt.gcode"]
    assert status["butterfly.gcode"].rstrip().endswith("ok")
    assert (out / "butterfly.gcode").exists() and not (out / "corrupt.gcode").exists()
    # a second run skips what is done
    r = CliRunner().invoke(cli, ["batch", str(src), "-o", str(out), "-j", "2", "--machine",
                                 "ender3pro"])
    assert "skipped" in r.output


def test_ctrl_c_leaves_no_half_written_file(tmp_path):
    src = tmp_path / "jobs"
    src.mkdir()
    shutil.copy(GCODE_DIR / "cura-4.11_ender3_3dbenchy.gcode", src / "a.gcode")
    shutil.copy(GCODE_DIR / "prusaslicer-2.6.1_mini_3dbenchy.gcode", src / "b.gcode")
    before = {p.name: p.read_bytes() for p in src.iterdir()}
    p = subprocess.Popen([sys.executable, "-m", "gcode_feedopt", "batch", str(src), "-j", "2",
                          "--machine", "ender3pro"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         start_new_session=True)
    time.sleep(4.0)
    os.killpg(p.pid, signal.SIGINT)
    out, err = p.communicate(timeout=60)
    # issue 18: the table says what was done even on Ctrl-C; exit 128 + SIGINT
    assert p.returncode == 130, err
    assert out.split()[:5] == [b"file", b"before", b"after", b"saved", b"status"], out
    assert b"a.gcode" in out and b"b.gcode" in out and b"stopped by" in err
    names = sorted(x.name for x in src.iterdir())
    assert names == ["a.gcode", "b.gcode"]  # no temp left behind
    for x in src.iterdir():  # each file is either untouched or completely processed
        data = x.read_bytes()
        assert data == before[x.name] or b"; processed by gcode-feedopt" in data[:4096]


def test_plot_and_dry_run(tmp_path):
    src = REPO / "sample_gcode" / "butterfly.gcode"
    before = src.read_bytes()
    png = tmp_path / "run.png"
    r = CliRunner().invoke(cli, [str(src), "--machine", "ender3pro", "--dry-run", "--plot",
                                 str(png), "--report", str(tmp_path / "r.json")])
    assert r.exit_code == 0, r.output
    assert src.read_bytes() == before  # dry run writes nothing
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000
    assert "dry run" in r.output


def test_batch_makes_again_what_other_settings_made(tmp_path):
    """issue 18: the ident line records the run's settings; an output made with others (here
    the tolerance, then the method) is made again, one made with the same is up to date."""
    src = tmp_path / "jobs"
    src.mkdir()
    shutil.copy(REPO / "sample_gcode" / "butterfly.gcode", src / "butterfly.gcode")
    out = tmp_path / "out"

    def run(*extra):
        r = CliRunner().invoke(cli, ["batch", str(src), "-o", str(out), "-j", "1", "--machine",
                                     "ender3pro", *extra])
        assert r.exit_code == 0, r.output
        return r.output.splitlines()[1]

    assert run().rstrip().endswith("ok")
    head = (out / "butterfly.gcode").read_bytes()[:4096]
    assert b"[machine ender3pro@" in head and b"method pidd, speed slicer, tolerance 0.1," in head
    assert "skipped" in run()
    assert run("--tolerance", "0.2").rstrip().endswith("ok")
    assert b"tolerance 0.2," in (out / "butterfly.gcode").read_bytes()[:4096]
    assert "skipped" in run("--tolerance", "0.2")
    assert run("--tolerance", "0.2", "--method", "kinematic").rstrip().endswith("ok")


def test_batch_report_dir_one_json_per_processed_file(tmp_path):
    import json

    src = tmp_path / "jobs"
    src.mkdir()
    shutil.copy(REPO / "sample_gcode" / "butterfly.gcode", src / "butterfly.gcode")
    (src / "corrupt.gcode").write_bytes(b"GCDE\x00\x01binary")
    out, rep = tmp_path / "out", tmp_path / "reports"
    # a report folder whose parent is missing: one line, exit 2, nothing made
    r = CliRunner().invoke(cli, ["batch", str(src), "-o", str(out), "--machine", "ender3pro",
                                 "--report", str(tmp_path / "no" / "reports")])
    assert r.exit_code == 2 and "does not exist" in r.output and not out.exists()
    r = CliRunner().invoke(cli, ["batch", str(src), "-o", str(out), "-j", "1", "--machine",
                                 "ender3pro", "--method", "kinematic", "--report", str(rep)])
    assert r.exit_code == 1  # the corrupt file fails alone
    assert sorted(p.name for p in rep.iterdir()) == ["butterfly.json"]
    d = json.loads((rep / "butterfly.json").read_text())
    assert d["method"] == "kinematic" and d["output"] == str(out / "butterfly.gcode")
    row = next(ln for ln in r.output.splitlines() if ln.startswith("butterfly.gcode"))
    assert row.rstrip().endswith(("ok", "kept"))


def test_batch_table_writes_times_as_the_summary_does():
    """The table's times are the summary's (report.hms): rounded once, hours shown; before,
    359.6 s was '5m60s' and 3725 s '62m05s'."""
    from gcode_feedopt.hosts.batch import JobResult, table
    from gcode_feedopt.report import hms

    t = table([JobResult("a.gcode", "ok", 3725.0, 359.6)])
    row = t.splitlines()[1].split()
    assert row[1:3] == ["1h02m05s", "6m00s"] == [hms(3725.0), hms(359.6)]


def test_batch_shows_the_main_commands_notes(tmp_path):
    """issue 18: batch shows the notes the summary would (here --mode sampled above ender3pro's
    line budget, once for all files), and what a single file has alone, named."""
    src = tmp_path / "jobs"
    src.mkdir()
    data = (REPO / "sample_gcode" / "butterfly.gcode").read_bytes()
    (src / "a.gcode").write_bytes(data)
    (src / "b.gcode").write_bytes(data.rstrip(b"\r\n"))  # no line end on its last line
    r = CliRunner().invoke(cli, ["batch", str(src), "-o", str(tmp_path / "out"), "-j", "1",
                                 "--machine", "ender3pro", "--method", "kinematic",
                                 "--mode", "sampled", "--allow-slower"])
    assert r.exit_code == 0, r.output
    notes = [ln for ln in r.output.splitlines() if ln.startswith("note: ")]
    assert any(n.startswith("note: all 2 files: --mode sampled") and "max_lines_per_s" in n
               for n in notes), r.output
    assert any(n.startswith("note: b.gcode: the last line") for n in notes), r.output
    assert not any(n.startswith("note: a.gcode") for n in notes), r.output
