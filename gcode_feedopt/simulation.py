"""A G-code file on the virtual machine, without click: the simulator API.

G-code -> firmware model (``vm.firmware``, Marlin or Klipper per profile) -> commanded
trajectory -> plant (one seeded draw of the profile's FRFs plus effects) -> metrics.
``gcode-feedopt simulate`` (``cli/simulate.py``) is the command over it; benchmarks and
other stages call ``simulate_file`` / ``simulate_program`` / ``simulate_trajectory``.
It sits beside ``pipeline.py`` (which it reads files through), above ``vm/``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from .pipeline import read_for
from .vm import firmware, metrics
from .vm.plant import Plant

#: samples the contour error can be judged on (``vm.metrics.evaluate``'s ``on``)
CONTOUR_ON = ("extrusion", "xy")


@dataclass(frozen=True)
class SimulationResult:
    """Everything one simulated run produced.

    Attributes:
        trajectory: the firmware's commanded trajectory (``vm.trajectory.Trajectory``).
        output: ``vm.plant.PlantOutput`` (actual and measured positions, impulse responses).
        metrics: ``vm.metrics.Metrics``.
        timings_s: stage -> wall-clock seconds (read, firmware, plant, metrics).
    """

    trajectory: object
    output: object
    metrics: object
    timings_s: dict = field(default_factory=dict)


def simulate_program(program, profile, *, seed: int = 0, effects=(), tol_mm: float | None = None,
                     contour_on: str = "extrusion", nominal: bool = False) -> SimulationResult:
    """Execute a read Program on the virtual machine; no files are opened."""
    timings = {}
    t0 = time.perf_counter()
    trajectory = firmware.execute(program, profile)
    timings["firmware"] = time.perf_counter() - t0
    return simulate_trajectory(trajectory, profile, seed=seed, effects=effects, tol_mm=tol_mm,
                               contour_on=contour_on, timings_s=timings, nominal=nominal)


def simulate_trajectory(trajectory, profile, *, seed: int = 0, effects=(), tol_mm: float | None = None,
                        contour_on: str = "extrusion", timings_s: dict | None = None,
                        nominal: bool = False) -> SimulationResult:
    """Run a commanded trajectory through the seeded plant and evaluate it."""
    timings = dict(timings_s or {})
    tol = float(profile.limits.tolerance_mm if tol_mm is None else tol_mm)
    t0 = time.perf_counter()
    output = Plant(profile, seed=seed, effects=effects, nominal=nominal).simulate(trajectory)
    timings["plant"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = metrics.evaluate(trajectory, output.actual_mm, tol, on=contour_on)
    timings["metrics"] = time.perf_counter() - t0
    return SimulationResult(trajectory=trajectory, output=output, metrics=result, timings_s=timings)


def read_program(path, profile):
    """Read a G-code file into a Program with the profile's firmware semantics."""
    return read_for(path, profile)


def simulate_file(path, profile, **kwargs) -> SimulationResult:
    """Read ``path`` and ``simulate_program`` it; ``timings_s`` gains ``read``."""
    t0 = time.perf_counter()
    program = read_program(path, profile)
    t_read = time.perf_counter() - t0
    res = simulate_program(program, profile, **kwargs)
    res.timings_s["read"] = t_read
    return res
