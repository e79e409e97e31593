"""PrusaSlicer / SuperSlicer / OrcaSlicer post-processing.

The slicer runs ``post_process`` commands with the G-code's (temporary) path as the last
argument and expects the file edited in place; a non-zero exit aborts the export and shows
the last lines of stderr. On Windows stderr is lost, so a failure is also written to a log file
beside the G-code. The slicer passes its settings as ``SLIC3R_*`` environment variables; the
ones that describe the machine's limits are compared with the profile.
"""

from __future__ import annotations

import datetime
import os
import pathlib

from ..errors import FeedOptError
from ..outputs import write_bytes

#: SLIC3R variables holding machine limits, and the profile value each one corresponds to.
LIMIT_VARS = {
    "SLIC3R_MACHINE_MAX_ACCELERATION_X": ("firmware.max_accel_mm_s2.x", 1.0),
    "SLIC3R_MACHINE_MAX_ACCELERATION_Y": ("firmware.max_accel_mm_s2.y", 1.0),
    "SLIC3R_MACHINE_MAX_FEEDRATE_X": ("firmware.max_feed_mm_s.x", 1.0),
    "SLIC3R_MACHINE_MAX_FEEDRATE_Y": ("firmware.max_feed_mm_s.y", 1.0),
    "SLIC3R_MACHINE_MAX_JUNCTION_DEVIATION": ("firmware.junction_deviation_mm", 1.0),
}


def running_in_slicer(env=None) -> bool:
    env = os.environ if env is None else env
    return any(k in env for k in ("SLIC3R_PP_OUTPUT_NAME", "SLIC3R_PP_HOST", "SLIC3R_LAYER_HEIGHT"))


def output_name(env=None) -> str | None:
    """The final file name the slicer will give the G-code (SLIC3R_PP_OUTPUT_NAME)."""
    env = os.environ if env is None else env
    return env.get("SLIC3R_PP_OUTPUT_NAME")


def _get(profile, dotted: str) -> float:
    obj = profile
    for part in dotted.split("."):
        obj = obj[part] if isinstance(obj, dict) else getattr(obj, part)
    return float(obj)


def limit_disagreements(profile, env=None) -> list[str]:
    """One sentence per SLIC3R machine limit that differs from the profile by more than 1 %."""
    env = os.environ if env is None else env
    out = []
    for var, (key, scale) in LIMIT_VARS.items():
        raw = env.get(var)
        if raw is None:
            continue
        try:
            # PrusaSlicer passes per-mode lists as "3000,3000"; the first is the normal mode
            v = float(raw.split(",")[0]) * scale
        except ValueError:
            continue
        p = _get(profile, key)
        if p > 0 and abs(v - p) > 0.01 * p:
            out.append(f"slicer {var.removeprefix('SLIC3R_').lower()} = {v:g} but profile "
                       f"{profile.name} {key} = {p:g}; the plan follows the profile")
    return out


def write_failure_log(gcode_path: pathlib.Path, message: str) -> pathlib.Path | None:
    """Write the failure next to the G-code (and say where), for hosts that drop stderr."""
    log = pathlib.Path(str(gcode_path) + ".feedopt.log")
    line = f"{datetime.datetime.now().isoformat(timespec='seconds')} {message}\n".encode()
    try:  # appended through the one safe-write path (outputs.py): never a device, no debris
        old = log.read_bytes() if log.is_file() else b""
        write_bytes(log, old + line)
        return log
    except (OSError, FeedOptError):
        return None
