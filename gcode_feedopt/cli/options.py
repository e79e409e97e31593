"""Options shared by the sub-commands: bounded numbers (one rule, one message shape, the
same limits in every command) and the profile file an output must not replace.

Every numeric option is parsed by ``Bounded``: NaN and infinities are refused, and the value
must lie in a stated range. The ranges are those of the profile schema where the option
overrides a profile value (``profile/io.py``: V_max ≤ 5000 mm/s, A_max ≤ 1e6 mm/s²,
tolerance ≤ 10 mm, stringency 0.5–0.9999), with lower limits that keep a plan's size sane:
a plan has one sample per Ts (2 ms), so ``--vmax 1e-6`` on a Benchy would ask for hundreds of
GiB; the plan's size is also checked against its file (pipeline.check_plan_size).
"""

from __future__ import annotations

import math
import pathlib

import click

#: option -> (low, high, unit): the one table of numeric limits
LIMITS = {
    "vmax": (0.1, 5000.0, "mm/s"),
    "amax": (1.0, 1e6, "mm/s²"),
    "tolerance": (0.001, 10.0, "mm"),
    "stringency": (0.5, 0.9999, ""),
    "seed": (0, 2**32 - 1, ""),
    "fit_fraction": (0.1, 0.9, ""),
    "freq_hz": (1.0, 2000.0, "Hz"),
    "hz_per_sec": (0.01, 1000.0, "Hz/s"),
    "accel_per_hz": (0.1, 10000.0, "mm/s² per Hz"),
    "sweeping_accel": (0.0, 1e5, "mm/s²"),
    "sweeping_period": (0.0, 100.0, "s"),
}


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


class Bounded(click.ParamType):
    """A finite number within [low, high] (an integer when ``integer``)."""

    def __init__(self, key: str, integer: bool = False):
        self.low, self.high, self.unit = LIMITS[key]
        self.integer = integer
        self.name = "integer" if integer else "number"

    def get_metavar(self, param, ctx=None):  # click >= 8.2 passes ctx
        return f"[{_fmt(self.low)}-{_fmt(self.high)}]"

    def convert(self, value, param, ctx):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            x = value
        else:
            text = str(value).strip()
            if len(text) > 40:
                text = text[:37] + "..."
            try:
                x = int(text) if self.integer else float(text)
            except ValueError:
                self.fail(f"'{text}' is not {'an integer' if self.integer else 'a number'}; "
                          f"give {self._range()}", param, ctx)
        if not self.integer and not math.isfinite(x):
            self.fail(f"{x} is not a finite number; give {self._range()}", param, ctx)
        if x < self.low or x > self.high:
            side = "below the smallest" if x < self.low else "above the largest"
            lim = self.low if x < self.low else self.high
            self.fail(f"{_fmt(x)} is {side} supported value {_fmt(lim)}"
                      f"{' ' + self.unit if self.unit else ''}; give {self._range()}", param, ctx)
        return x

    def _range(self) -> str:
        u = f" {self.unit}" if self.unit else ""
        return f"a value from {_fmt(self.low)} to {_fmt(self.high)}{u}"


VMAX = Bounded("vmax")
AMAX = Bounded("amax")
TOLERANCE = Bounded("tolerance")
STRINGENCY = Bounded("stringency")
SEED = Bounded("seed", integer=True)


def profile_files(machine: str) -> list[pathlib.Path]:
    """The profile file ``--machine`` names, when it is a file (an input no output may
    replace)."""
    p = pathlib.Path(machine)
    return [p] if p.suffix.lower() in (".yaml", ".yml") and p.is_file() else []


def speed_policy(speed: str, use_slicer_feed: bool) -> str:
    """``--speed``, with the old ``--use-slicer-feed`` flag meaning ``slicer`` (kept so users'
    scripts keep working; it is the default now)."""
    return "slicer" if use_slicer_feed else speed


#: --accel on optimize and batch (the PrusaSlicer hook and the Cura script run optimize with
#: its default)
ACCEL_HELP = ("plan: the plan's accelerations and junctions (the profile's hardware limits, "
              "limits.axis_jerk_mm_s for junctions, lowered by the twin where the tolerance needs "
              "it) override lower ones the file sets (M204 P/T/S, M201 X/Y, M205 X/Y/J, "
              "SET_VELOCITY_LIMIT ACCEL/SQUARE_CORNER_VELOCITY): a line after each sets the "
              "plan's again; retraction accelerations stay the file's. file: the file's own "
              "accelerations and the firmware's and the file's junction settings are kept.")


#: --feature-tolerance on optimize and batch (parsed in the command: a bad value is a
#: one-line error, exit 2)
FEATURE_TOLERANCE_HELP = (
    "E_max per slicer feature, e.g. outer_wall=0.05,infill=0.3 ('defaults': outer_wall 0.05, "
    "inner_wall/skin/bridge 0.1, infill/support/skirt 0.3; 'off': one tolerance). Features: "
    "outer_wall inner_wall skin infill bridge support skirt travel other; others keep "
    "--tolerance; travel has none. Default: the profile's limits.feature_tolerance_mm.")


class Progress:
    """One self-overwriting line on stderr naming the stage and the time so far, refreshed
    every second (the CLI creates one only when stderr is a terminal and not --quiet: print
    hosts, pipes and logs get nothing). Call it with a stage name; ``done`` stops it and clears
    the line."""

    def __init__(self, name: str):
        import threading
        import time

        self._clock = time.perf_counter
        self.t0 = self._clock()
        self.name = name
        self.stage = ""
        self.width = 0
        self._lock = threading.Lock()
        self._stop = threading.Event()
        # planning forks worker processes while the ticker runs: a fork in the middle of its
        # write would hand the child a stderr whose lock no thread will ever release (a worker
        # writing a warning would hang). Each fork waits for the line to be written.
        import os
        if hasattr(os, "register_at_fork"):
            os.register_at_fork(before=self._lock.acquire,
                                after_in_parent=self._lock.release,
                                after_in_child=self._forked)
        self._thread = threading.Thread(target=self._tick, daemon=True)
        self._thread.start()

    def _forked(self) -> None:
        """In a forked child: no ticker there; the lock taken before the fork is free again."""
        self._stop.set()
        self._lock.release()

    def _tick(self) -> None:
        while not self._stop.wait(1.0):
            self._show()

    def _show(self) -> None:
        with self._lock:
            if not self.stage or self._stop.is_set():
                return
            text = f"{self.name}: {self.stage} … {self._clock() - self.t0:.0f} s"
            click.echo("\r" + text.ljust(self.width), err=True, nl=False)
            self.width = max(self.width, len(text))

    def __call__(self, stage: str) -> None:
        self.stage = stage
        self._show()

    def clear(self) -> None:
        """Erase the line until the next stage (before other text goes to the terminal)."""
        with self._lock:
            self.stage = ""
            if self.width:
                click.echo("\r" + " " * self.width + "\r", err=True, nl=False)
                self.width = 0

    def done(self) -> None:
        with self._lock:
            self._stop.set()
            if self.width:
                click.echo("\r" + " " * self.width + "\r", err=True, nl=False)
        self._thread.join(timeout=2.0)
