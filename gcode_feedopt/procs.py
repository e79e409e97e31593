"""Signals and worker processes: SIGTERM (what print hosts and systemd send) and SIGHUP are
handled like Ctrl-C, and no worker process outlives the command.

- The main process turns SIGINT, SIGTERM and SIGHUP into ``errors.Interrupted`` (a
  KeyboardInterrupt), so every ``with``/``finally`` on the way out runs: temporary files are
  removed (outputs.py) and worker pools are stopped (``worker_pool``). The CLI then prints one
  line and exits 128 + the signal number (130 for Ctrl-C, 143 for SIGTERM).
- Workers ignore SIGINT and SIGHUP (the parent decides) and on SIGTERM remove their temporary
  files and exit at once; on Linux they also get SIGTERM when the parent dies, even by SIGKILL
  (``PR_SET_PDEATHSIG``), so none is left blocked on a queue.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from concurrent.futures import (FIRST_COMPLETED, Future, ProcessPoolExecutor, TimeoutError,
                                wait)

from .errors import Interrupted
from .outputs import remove_temps

#: signals the main process turns into Interrupted
HANDLED = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))
#: longest uninterrupted wait of the main thread for a worker's result, s
POLL_S = 0.2
#: seconds a terminated worker gets to remove its temporary files before SIGKILL
WORKER_GRACE_S = 5.0


#: the signal being handled (None: none yet) and whether the way out has begun
_STATE = {"signum": None, "acknowledged": False, "pid": None}
#: seconds after which a signal whose exception was swallowed is sent again
RESEND_S = 0.5


def _resender(signum: int) -> None:
    # Python drops an exception raised where it cannot propagate (an at-fork hook, __del__,
    # a weakref callback): send the signal to the main thread again until someone takes it
    # (acknowledge). This thread itself never takes the signals.
    _block_here()
    while True:
        time.sleep(RESEND_S)
        if _STATE["acknowledged"]:
            return
        signal.pthread_kill(threading.main_thread().ident, signum)


def _arm_resend(signum: int) -> None:
    threading.Thread(target=_resender, args=(signum,), daemon=True,
                     name="gcode-feedopt-resend").start()


def _block_here() -> None:
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_BLOCK, HANDLED)


@contextlib.contextmanager
def _signals_blocked():
    """Block the handled signals in this thread for the ``with`` body: threads and processes
    started meanwhile inherit the mask (only the main thread takes them; a fork cannot lose
    one in an at-fork hook). A signal arriving meanwhile is delivered on exit."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, HANDLED)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _raise_interrupted(signum, frame):
    if os.getpid() != _STATE["pid"]:  # a worker forked just now, before worker_init ran
        _worker_term(signum, frame)
    if _STATE["acknowledged"]:
        return
    if _STATE["signum"] is None:
        _STATE["signum"] = signum
        _arm_resend(signum)
    raise Interrupted(_STATE["signum"])


def acknowledge() -> None:
    """The Interrupted exception reached code that cleans up: from now on further signals
    are ignored, so the cleanup (stopping workers, removing temporary files) is not cut short."""
    if _STATE["signum"] is None or _STATE["acknowledged"]:
        return
    _STATE["acknowledged"] = True
    if threading.current_thread() is threading.main_thread():
        for s in HANDLED:
            signal.signal(s, signal.SIG_IGN)


def install_handlers() -> None:
    """Main process: SIGINT, SIGTERM, SIGHUP raise Interrupted (only from the main thread)."""
    _STATE.update(signum=None, acknowledged=False, pid=os.getpid())
    previous = sys.unraisablehook

    def quiet_interrupt(unraisable):
        # an Interrupted raised where Python cannot propagate it: _resend sends it again
        if not isinstance(unraisable.exc_value, Interrupted):
            previous(unraisable)

    sys.unraisablehook = quiet_interrupt
    for s in HANDLED:
        if s == getattr(signal, "SIGHUP", None) and signal.getsignal(s) == signal.SIG_IGN:
            continue  # started under nohup: keep ignoring hang-ups
        signal.signal(s, _raise_interrupted)


def signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def _worker_term(signum, frame):
    # the last act of a worker: a second SIGTERM (the pool's manager thread terminates the
    # workers too) must not re-enter, and nothing may keep the worker from exiting
    signal.signal(signum, signal.SIG_IGN)
    try:
        remove_temps()
    finally:
        os._exit(128 + signum)


def _set_parent_death_signal() -> None:
    if not sys.platform.startswith("linux"):
        return
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        PR_SET_PDEATHSIG = 1
        libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):
        pass


def worker_init(parent_pid: int) -> None:
    """Initializer of every worker process."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "SIGHUP"):
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_term)
    if hasattr(signal, "pthread_sigmask"):  # forked with them blocked (_signals_blocked)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, HANDLED)
    _set_parent_death_signal()
    if os.getppid() != parent_pid:  # the parent died before the line above
        os._exit(1)


def stop_pool(pool: ProcessPoolExecutor) -> None:
    """Cancel what is queued, terminate the workers (they remove their temporary files) and
    reap them; SIGKILL after WORKER_GRACE_S."""
    procs = list((getattr(pool, "_processes", None) or {}).values())
    # shutdown(wait=False) forgets the executor's manager thread, which may be reaping a
    # worker at this moment (between its waitpid and setting the exit code, the process
    # looks alive to every other thread): keep it and join it below
    manager = getattr(pool, "_executor_manager_thread", None)
    # the call queue's feeder thread may be blocked writing a large task into the pipe of a
    # worker we are about to stop; at exit multiprocessing joins that thread without a
    # timeout, and the run hung after its "stopped by SIGTERM" line (tests/test_signals.py,
    # once in three CI runs, 2026-11-27): nothing queued is wanted any more
    with contextlib.suppress(Exception):
        pool._call_queue.cancel_join_thread()
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        with contextlib.suppress(Exception):
            p.terminate()
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(WORKER_GRACE_S)
            if p.is_alive():
                p.kill()
                p.join(WORKER_GRACE_S)
    with contextlib.suppress(Exception):  # reap the manager thread now, not at exit
        pool.shutdown(wait=True)
        if manager is not None:
            manager.join(WORKER_GRACE_S)
    for p in procs:  # a join that raced with the manager's may have returned early
        with contextlib.suppress(Exception):
            deadline = time.monotonic() + WORKER_GRACE_S
            while p.is_alive() and time.monotonic() < deadline:
                p.join(0.05)


def _wait(fut: Future):
    # never an unbounded wait: the main thread wakes every POLL_S, so a signal taken by any
    # other thread (numpy's, the pool's) still runs its handler here
    while True:
        try:
            return fut.result(timeout=POLL_S)
        except TimeoutError:
            continue


class Pool:
    """The parts of ProcessPoolExecutor we use, made safe for signals: workers are forked
    and helper threads started with the handled signals blocked, and results are waited for
    in short slices."""

    def __init__(self, pool: ProcessPoolExecutor):
        self.executor = pool

    def submit(self, fn, /, *args, **kwargs) -> Future:
        with _signals_blocked():
            return self.executor.submit(fn, *args, **kwargs)

    def map(self, fn, *iterables):
        """Like Executor.map (results in order), submitted at once."""
        with _signals_blocked():
            futs = [self.executor.submit(fn, *args) for args in zip(*iterables)]

        def results():
            for f in futs:
                yield _wait(f)
        return results()

    def as_completed(self, futs):
        """Like concurrent.futures.as_completed, waiting in short slices."""
        pending = set(futs)
        while pending:
            done, pending = wait(pending, timeout=POLL_S, return_when=FIRST_COMPLETED)
            yield from done


@contextlib.contextmanager
def worker_pool(max_workers: int, mp_context=None):
    """A ``Pool`` whose workers are stopped on any exception, Ctrl-C or SIGTERM in the
    ``with`` body (never left running or blocked), and shut down normally otherwise."""
    ex = ProcessPoolExecutor(max_workers=max_workers, mp_context=mp_context,
                             initializer=worker_init, initargs=(os.getpid(),))
    try:
        yield Pool(ex)
    except BaseException as exc:
        if isinstance(exc, KeyboardInterrupt):
            acknowledge()
        stop_pool(ex)
        raise
    ex.shutdown(wait=True)
