"""The one safe-write path (gcode_feedopt.outputs): checks before work, temp + fsync +
os.replace, modes, owners, symlinks, devices, long names, no debris on any failure."""

from __future__ import annotations

import errno
import os
import pathlib
import stat
import subprocess
import sys

import pytest

from gcode_feedopt import outputs
from gcode_feedopt.errors import FeedOptError, OutputError

REPO = pathlib.Path(__file__).resolve().parents[1]
GOOD = b"G1 X10 Y10 F3000\nG1 X50 Y10 E2 F1200\nG1 X50 Y50 E4\n"


def names(folder: pathlib.Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def run_cli(*args, cwd, preexec=None, umask=None):
    env = dict(os.environ, PYTHONPATH=str(REPO))

    def pre():
        if umask is not None:
            os.umask(umask)
        if preexec is not None:
            preexec()

    return subprocess.run([sys.executable, "-m", "gcode_feedopt", *map(str, args)], cwd=cwd,
                          env=env, capture_output=True, text=True, preexec_fn=pre, timeout=300)


def test_new_file_mode_follows_umask(tmp_path):
    old = os.umask(0o022)
    try:
        outputs.write_bytes(tmp_path / "a.txt", b"x")
        os.umask(0o077)
        outputs.write_bytes(tmp_path / "b.txt", b"x")
    finally:
        os.umask(old)
    assert stat.S_IMODE(os.stat(tmp_path / "a.txt").st_mode) == 0o644
    assert stat.S_IMODE(os.stat(tmp_path / "b.txt").st_mode) == 0o600


def test_replace_keeps_mode_and_owner(tmp_path):
    p = tmp_path / "f.gcode"
    p.write_bytes(b"old")
    os.chmod(p, 0o640)
    if os.geteuid() == 0:
        os.chown(p, 12345, 23456)
    ino = os.stat(p).st_ino
    outputs.write_bytes(p, b"new")
    st = os.stat(p)
    assert p.read_bytes() == b"new" and stat.S_IMODE(st.st_mode) == 0o640
    assert st.st_ino != ino  # replaced, not rewritten in place
    if os.geteuid() == 0:
        assert (st.st_uid, st.st_gid) == (12345, 23456)
    assert names(tmp_path) == ["f.gcode"]


def test_symlink_writes_the_real_file_and_keeps_the_link(tmp_path):
    real = tmp_path / "real.gcode"
    real.write_bytes(b"old")
    link = tmp_path / "link.gcode"
    link.symlink_to("real.gcode")
    outputs.write_bytes(link, b"new")
    assert link.is_symlink() and os.readlink(link) == "real.gcode"
    assert real.read_bytes() == b"new"


def test_dangling_symlink_creates_its_target(tmp_path):
    link = tmp_path / "link.csv"
    link.symlink_to("target.csv")
    outputs.write_text(link, "a\n")
    assert link.is_symlink() and (tmp_path / "target.csv").read_text() == "a\n"


def test_long_name_in_place(tmp_path):
    p = tmp_path / ("a" * 245 + ".gcode")  # 251 characters: the temp name must be shorter
    p.write_bytes(b"old")
    outputs.write_bytes(p, b"new")
    assert p.read_bytes() == b"new" and names(tmp_path) == [p.name]


def test_long_multibyte_name(tmp_path):
    p = tmp_path / ("é" * 100 + ".csv")  # 206 bytes
    outputs.write_bytes(p, b"x")
    assert p.read_bytes() == b"x" and names(tmp_path) == [p.name]


def test_name_too_long_is_refused(tmp_path):
    with pytest.raises(OutputError, match="longer than the file system"):
        outputs.check_output(tmp_path / ("a" * 300 + ".csv"), "--trajectory")


@pytest.mark.parametrize("dev", ["/dev/null", "/dev/full"])
def test_devices_are_refused_and_kept(dev):
    if not os.path.exists(dev):
        pytest.skip(f"no {dev}")
    with pytest.raises(OutputError, match="character device"):
        outputs.write_bytes(dev, b"x")
    assert stat.S_ISCHR(os.stat(dev).st_mode)


def test_fifo_refused_as_output_and_input(tmp_path):
    f = tmp_path / "pipe"
    os.mkfifo(f)
    with pytest.raises(OutputError, match="FIFO"):
        outputs.check_output(f)
    from gcode_feedopt.inputs import check_input

    with pytest.raises(FeedOptError, match="FIFO"):
        check_input(f)
    assert stat.S_ISFIFO(os.stat(f).st_mode)


def test_folder_rules(tmp_path):
    with pytest.raises(OutputError, match="does not exist; create it first"):
        outputs.check_output(tmp_path / "nodir" / "sub" / "x.csv", "-o")
    with pytest.raises(OutputError, match="is a folder"):
        outputs.check_output(tmp_path, "-o")
    (tmp_path / "file").write_bytes(b"")
    with pytest.raises(OutputError, match="not a folder"):
        outputs.check_output(tmp_path / "file" / "x.csv", "-o")
    assert not (tmp_path / "nodir").exists()


def test_input_and_duplicate_outputs_refused(tmp_path):
    src = tmp_path / "in.gcode"
    src.write_bytes(GOOD)
    os.link(src, tmp_path / "hard.gcode")
    (tmp_path / "sym.gcode").symlink_to("in.gcode")
    for p in ("in.gcode", "hard.gcode", "sym.gcode"):
        with pytest.raises(OutputError, match="is the input file"):
            outputs.check_outputs({"--log": tmp_path / p}, inputs=[src])
    outputs.check_outputs({"-o": src}, inputs=[src], in_place=["-o"])  # an in-place edit
    with pytest.raises(OutputError, match="both write"):
        outputs.check_outputs({"--report": tmp_path / "r.json",
                               "--trajectory": tmp_path / "." / "r.json"})
    with pytest.raises(OutputError, match="stdout"):
        outputs.check_outputs({"--report": "-", "--json": "-"})
    assert src.read_bytes() == GOOD


@pytest.mark.parametrize("err", [errno.ENOSPC, errno.EROFS, errno.EIO])
def test_write_errors_leave_nothing(tmp_path, monkeypatch, err):
    p = tmp_path / "f.gcode"
    p.write_bytes(b"old")

    def fail(fd):
        raise OSError(err, os.strerror(err))

    monkeypatch.setattr(outputs.os, "fsync", fail)
    with pytest.raises(OutputError, match="cannot write") as ei:
        outputs.write_bytes(p, b"new" * 1000)
    assert "\n" not in str(ei.value)
    assert p.read_bytes() == b"old" and names(tmp_path) == ["f.gcode"]
    assert not outputs._ACTIVE_TEMPS


@pytest.mark.parametrize("exc", [KeyboardInterrupt, ValueError, SystemExit])
def test_interrupt_inside_the_write_leaves_nothing(tmp_path, exc):
    p = tmp_path / "f.csv"
    p.write_bytes(b"old")
    with pytest.raises(exc):
        with outputs.output_file(p, text=True) as fh:
            fh.write("half a line")
            raise exc()
    assert p.read_bytes() == b"old" and names(tmp_path) == ["f.csv"]
    with pytest.raises(exc):
        with outputs.output_path(tmp_path / "p.png") as tmp:
            pathlib.Path(tmp).write_bytes(b"partial png")
            raise exc()
    assert names(tmp_path) == ["f.csv"]


def test_output_path_keeps_suffix_for_matplotlib(tmp_path):
    with outputs.output_path(tmp_path / "p.png") as tmp:
        assert tmp.endswith(".png") and os.path.dirname(tmp) == str(tmp_path)
        pathlib.Path(tmp).write_bytes(b"png")
    assert (tmp_path / "p.png").read_bytes() == b"png" and names(tmp_path) == ["p.png"]


def test_read_only_file_system_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(outputs, "_read_only_fs", lambda folder: True)
    with pytest.raises(OutputError, match="read-only file system"):
        outputs.check_output(tmp_path / "x.csv", "--log")


def test_make_output_folder(tmp_path):
    assert outputs.make_output_folder(tmp_path / "out").is_dir()
    with pytest.raises(OutputError, match="does not exist"):
        outputs.make_output_folder(tmp_path / "a" / "b")
    (tmp_path / "f").write_bytes(b"")
    with pytest.raises(OutputError, match="not a folder"):
        outputs.make_output_folder(tmp_path / "f")
    assert not (tmp_path / "a").exists()


# ---- through the command line ------------------------------------------------------------

def test_cli_created_files_are_0644(tmp_path):
    (tmp_path / "in.gcode").write_bytes(GOOD)
    r = run_cli("in.gcode", "-o", "out.gcode", "-m", "ender3pro", "--method", "kinematic", "-q",
                "--trajectory", "t.csv", "--report", "r.json", cwd=tmp_path, umask=0o022)
    assert r.returncode == 0, r.stderr
    for n in ("out.gcode", "t.csv", "r.json"):
        assert stat.S_IMODE(os.stat(tmp_path / n).st_mode) == 0o644, n


def test_cli_in_place_through_symlink_and_long_name(tmp_path):
    (tmp_path / "real.gcode").write_bytes(GOOD)
    os.chmod(tmp_path / "real.gcode", 0o640)
    (tmp_path / "link.gcode").symlink_to("real.gcode")
    r = run_cli("-m", "ender3pro", "--method", "kinematic", "-q", "link.gcode", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "link.gcode").is_symlink()
    assert b"processed by gcode-feedopt" in (tmp_path / "real.gcode").read_bytes()
    assert stat.S_IMODE(os.stat(tmp_path / "real.gcode").st_mode) == 0o640
    long = tmp_path / ("b" * 245 + ".gcode")
    long.write_bytes(GOOD)
    r = run_cli("-m", "ender3pro", "--method", "kinematic", "-q", long.name, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert b"processed by gcode-feedopt" in long.read_bytes()
    assert names(tmp_path) == sorted([long.name, "link.gcode", "real.gcode"])


def test_cli_file_size_limit_is_one_line_and_no_debris(tmp_path):
    """RLIMIT_FSIZE makes writes fail with EFBIG past 4 KiB: the disk-full path, for real."""
    import resource

    (tmp_path / "in.gcode").write_bytes(GOOD)
    r = run_cli("in.gcode", "-o", "out.gcode", "-m", "ender3pro", "--method", "kinematic",
                "-q", "--trajectory", "t.csv", cwd=tmp_path,
                preexec=lambda: resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096)))
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip()
    assert "\n" not in line and "cannot write" in line and len(line) <= 300
    assert names(tmp_path) == ["in.gcode"]
    assert (tmp_path / "in.gcode").read_bytes() == GOOD


def test_failure_log_is_appended_safely(tmp_path):
    from gcode_feedopt.hosts.prusaslicer import write_failure_log

    g = tmp_path / "p.gcode"
    g.write_bytes(GOOD)
    log = write_failure_log(g, "first")
    assert write_failure_log(g, "second") == log
    lines = log.read_text().splitlines()
    assert len(lines) == 2 and lines[0].endswith(" first") and lines[1].endswith(" second")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE(os.stat(log).st_mode) == 0o666 & ~mask
    assert names(tmp_path) == ["p.gcode", "p.gcode.feedopt.log"]
    assert write_failure_log(tmp_path / "nodir" / "x.gcode", "x") is None


def _private_mount_ok() -> bool:
    try:
        r = subprocess.run(["unshare", "-m", "sh", "-c", "mount -t tmpfs tmpfs /mnt"],
                           capture_output=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return False
    return r.returncode == 0


@pytest.mark.skipif(not sys.platform.startswith("linux") or not _private_mount_ok(),
                    reason="needs a private mount namespace (unshare -m, root)")
def test_cli_real_full_disk_and_read_only_file_system(tmp_path):
    """A 96 KiB tmpfs in a private mount namespace: --trajectory fills it (ENOSPC), then the
    file system is remounted read-only (EROFS) for an in-place edit."""
    src = REPO / "sample_gcode" / "butterfly.gcode"
    head = b"".join(src.read_bytes().splitlines(keepends=True)[:600])
    (tmp_path / "src.gcode").write_bytes(head)
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    script = f"""
set -e
mount -t tmpfs -o size=96k tmpfs {mnt}
cp {tmp_path}/src.gcode {mnt}/in.gcode
cd {mnt}
set +e
{sys.executable} -m gcode_feedopt in.gcode -m ender3pro --method kinematic -q --trajectory t.csv
echo "rc=$?"
ls -A; cmp -s in.gcode {tmp_path}/src.gcode && echo same
mount -o remount,ro {mnt}
{sys.executable} -m gcode_feedopt in.gcode -m ender3pro --method kinematic -q
echo "rc=$?"
ls -A; cmp -s in.gcode {tmp_path}/src.gcode && echo same
"""
    r = subprocess.run(["unshare", "-m", "sh", "-c", script], capture_output=True, text=True,
                       env=dict(os.environ, PYTHONPATH=str(REPO)), timeout=300)
    out, err = r.stdout.split(), r.stderr.strip().splitlines()
    assert out == ["rc=2", "in.gcode", "same", "rc=2", "in.gcode", "same"], (r.stdout, r.stderr)
    assert len(err) == 2 and all(len(x) <= 300 for x in err), err
    assert "No space left on device" in err[0] and "t.csv" in err[0]
    assert "read-only file system" in err[1] and "-o:" not in err[1]
