"""SIGTERM is handled like Ctrl-C at several points of a run: no process left, no temporary
or partial file, the input byte-identical, one line on stderr, exit 128 + signal."""

from __future__ import annotations

import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time

import pytest

from .conftest import GCODE_DIR

REPO = pathlib.Path(__file__).resolve().parents[1]
BENCHY = GCODE_DIR / "cura-4.11_ender3_3dbenchy.gcode"
TOWER = GCODE_DIR / "cura-4.8_ender3_square-tower.gcode"

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def processes_with(marker: str) -> list[int]:
    """PIDs of live (not zombie) processes whose command line contains ``marker``."""
    out = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/cmdline", "rb") as fh:
                cmd = fh.read()
            with open(f"/proc/{d}/stat") as fh:
                state = fh.read().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if marker.encode() in cmd and state != "Z":
            out.append(int(d))
    return out


def children(pid: int) -> list[int]:
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as fh:
            return [int(x) for x in fh.read().split()]
    except OSError:
        return []


def _default_hup():
    # the run as a terminal starts it: SIGHUP at its default, whatever the test runner
    # inherited (under nohup it is ignored, and gcode-feedopt keeps it ignored: procs.py)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)


def start(args, cwd, **env):
    return subprocess.Popen([sys.executable, "-m", "gcode_feedopt", *map(str, args)], cwd=cwd,
                            env=dict(os.environ, PYTHONPATH=str(REPO), **env),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=_default_hup)


def wait_for(cond, timeout_s: float, p: subprocess.Popen) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if cond():
            return True
        if p.poll() is not None:
            return False
        time.sleep(0.01)
    return False


def stop(p, sig, group: bool):
    if group:  # a terminal's Ctrl-C reaches every process of the group
        os.killpg(p.pid, sig)
    else:  # a print host or systemd signals the main process
        p.send_signal(sig)
    out, err = p.communicate(timeout=60)
    return p.returncode, out, err


def assert_clean(folder: pathlib.Path, expect: dict[str, bytes], marker: str, rc, err, sig):
    assert rc == 128 + sig, (rc, err)
    line = err.strip()
    assert "\n" not in line and len(line) <= 300 and "stopped by" in line, err
    assert "Traceback" not in err
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted(expect), names  # no temporary or partial file
    for n, data in expect.items():
        assert (folder / n).read_bytes() == data, n
    time.sleep(0.2)
    assert processes_with(marker) == [], "worker processes left"


@pytest.fixture()
def benchy(tmp_path):
    if not BENCHY.is_file():
        pytest.skip(f"{BENCHY} missing")
    src = tmp_path / "big.gcode"
    shutil.copy(BENCHY, src)
    return src


@pytest.mark.parametrize("sig,group", [(signal.SIGTERM, False), (signal.SIGINT, True)])
def test_signal_while_writing_leaves_no_temp(benchy, sig, group):
    """The 61 MB trajectory CSV takes seconds to write: signal once its temp file exists."""
    folder = benchy.parent
    data = benchy.read_bytes()
    p = start([benchy.name, "-o", "out.gcode", "-m", "ender3pro", "--method", "kinematic",
               "--trajectory", "t.csv", "-q"], folder)
    seen = wait_for(lambda: any(n.name.startswith(".t.csv.") for n in folder.iterdir()), 120, p)
    assert seen, p.communicate()
    rc, _, err = stop(p, sig, group)
    assert_clean(folder, {"big.gcode": data}, str(folder), rc, err, sig)


@pytest.mark.parametrize("sig,group,delay_s", [
    (signal.SIGTERM, False, 0.0),  # while the workers are being forked
    pytest.param(signal.SIGTERM, False, 2.0, marks=pytest.mark.slow),  # while they plan
    (signal.SIGINT, True, 0.5),    # Ctrl-C in a terminal: every process of the group
    pytest.param(signal.SIGHUP, False, 1.0, marks=pytest.mark.slow),  # the terminal closed
])
def test_signal_while_workers_plan(benchy, sig, group, delay_s):
    """pidd plans a Benchy in worker processes: signal at several points; none may be left."""
    folder = benchy.parent
    data = benchy.read_bytes()
    p = start(["-m", "ender3pro", benchy.name], folder, GCODE_FEEDOPT_JOBS="2")
    assert wait_for(lambda: len(children(p.pid)) >= 1, 180, p), p.communicate()
    time.sleep(delay_s)
    rc, _, err = stop(p, sig, group)
    assert_clean(folder, {"big.gcode": data}, str(folder), rc, err, sig)


@pytest.mark.slow
def test_workers_die_with_a_killed_parent(benchy):
    """SIGKILL cannot be handled: the workers still go (PR_SET_PDEATHSIG), none blocks."""
    folder = benchy.parent
    p = start(["-m", "ender3pro", benchy.name], folder, GCODE_FEEDOPT_JOBS="2")
    assert wait_for(lambda: len(children(p.pid)) >= 2, 180, p), p.communicate()
    time.sleep(0.5)
    p.kill()
    p.communicate(timeout=30)
    t_end = time.monotonic() + 10
    while processes_with(str(folder)) and time.monotonic() < t_end:
        time.sleep(0.1)
    assert processes_with(str(folder)) == []


def test_sigterm_early_while_reading(tmp_path):
    src = tmp_path / "in.gcode"
    shutil.copy(TOWER if TOWER.is_file() else REPO / "sample_gcode" / "butterfly.gcode", src)
    data = src.read_bytes()
    p = start(["-m", "ender3pro", "in.gcode", "--report", "r.json"], tmp_path)
    time.sleep(1.0)  # imports and parsing
    if p.poll() is not None:
        pytest.skip("finished before the signal")
    rc, _, err = stop(p, signal.SIGTERM, False)
    assert_clean(tmp_path, {"in.gcode": data}, str(tmp_path), rc, err, signal.SIGTERM)


def test_sigterm_batch_stops_workers_and_prints_the_table(tmp_path):
    if not BENCHY.is_file():
        pytest.skip(f"{BENCHY} missing")
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    names = ["a.gcode", "b.gcode", "c.gcode", "d.gcode"]
    for n in names:
        shutil.copy(BENCHY, jobs / n)
    data = BENCHY.read_bytes()
    p = start(["batch", "jobs", "-j", "2", "-m", "ender3pro"], tmp_path)
    assert wait_for(lambda: len(children(p.pid)) >= 2, 60, p)
    time.sleep(3.0)
    t0 = time.monotonic()
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=60)
    assert time.monotonic() - t0 < 15  # stops at once, does not finish the running jobs
    assert p.returncode == 128 + signal.SIGTERM, err
    assert "Traceback" not in err and "stopped by SIGTERM" in err
    assert sorted(x.name for x in jobs.iterdir()) == names  # no temp left
    for n in names:  # every file untouched or completely processed, and the table says which
        row = next(r for r in out.splitlines() if r.startswith(n))
        if (jobs / n).read_bytes() == data:
            assert "interrupted" in row, row
        else:
            assert b"; processed by gcode-feedopt" in (jobs / n).read_bytes()[:4096]
            assert " ok" in row, row
    time.sleep(0.2)
    assert processes_with(str(tmp_path)) == []


def _sleep(x):
    time.sleep(x)
    return x


def test_worker_pool_map_order_and_stop_on_interrupt():
    from gcode_feedopt import procs

    with procs.worker_pool(2) as pool:
        assert list(pool.map(_sleep, [0.2, 0.0, 0.1])) == [0.2, 0.0, 0.1]
        assert sorted(f.result() for f in pool.as_completed([pool.submit(_sleep, 0.0)])) == [0.0]
    t0 = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        with procs.worker_pool(2) as pool:
            [pool.submit(_sleep, 30) for _ in range(4)]
            workers = list(pool.executor._processes.values())
            time.sleep(0.3)
            raise KeyboardInterrupt
    assert time.monotonic() - t0 < 10  # the running 30 s jobs were not waited for
    assert workers and not any(w.is_alive() for w in workers)


def test_worker_exits_on_a_repeated_sigterm():
    # the pool's manager thread terminates workers too: a second SIGTERM arriving while the
    # first one's handler runs must not leave the worker running (it used to re-enter an
    # import, fail, and go on with the next job until SIGKILL five seconds later)
    from gcode_feedopt import procs

    for _ in range(5):
        with pytest.raises(KeyboardInterrupt):
            with procs.worker_pool(2) as pool:
                [pool.submit(_sleep, 30) for _ in range(4)]
                workers = list(pool.executor._processes.values())
                time.sleep(0.3)
                for _ in range(3):
                    for w in workers:
                        w.terminate()
                raise KeyboardInterrupt
        assert [w.exitcode for w in workers] == [143, 143]  # by its handler, not SIGKILL
