"""``gcode-feedopt predict --machine M log.csv -o pred.csv`` — run the twin over a log.

The log is an encoder log (``t,x_cmd,y_cmd[,x,y]``) or a plan written by ``optimize
--trajectory`` (``t,x,y,z,e``: commands only). A log that starts mid-motion (cut mid-print) is
predicted from its first row with the history held there, but its first ``twin_memory``
samples depend on motion before the log: the twin does not learn from them and the summary
leaves them out (one-line warning; ``closedloop.logs``)."""

from __future__ import annotations

import pathlib

import warnings

import click
import numpy as np

from ..closedloop.logs import check_log_period, resample_columns
from ..errors import LogError, LogWarning
from ..inputs import check_input, read_text
from ..outputs import check_outputs, output_file
from ..profile import load_profile
from ..twin.extensions import extra_variance_mm2, mean_offsets
from .options import profile_files


#: largest |value| in a log: positions in mm (a 10 m machine is 1e4) and times in s (a week
#: is 6e5)
MAX_LOG_ABS = 1e7


def read_log_columns(path: pathlib.Path, ts_s: float):
    """t, x_cmd, y_cmd and (if present) x, y from a log; refuses malformed logs. A plan from
    ``optimize --trajectory`` (header ``t,x,y,z,e``) gives its x, y as the commands."""
    lines = read_text(path, "a log (t,x_cmd,y_cmd[,x,y])", LogError).splitlines()
    header = lines[0].strip() if lines else ""
    cols = [c.strip() for c in header.split(",")]
    planned = cols == ["t", "x", "y", "z", "e"]
    for need in ("t", "x_cmd", "y_cmd"):
        if need not in cols and not planned:
            raise LogError(f"{path}:1: column '{need}' missing; a log starts with the header "
                           "t,x_cmd,y_cmd[,x,y] (s, mm), a plan (optimize --trajectory) with "
                           "t,x,y,z,e")
    if len([ln for ln in lines[1:] if ln.strip()]) < 10:
        raise LogError(f"{path}: only {max(len(lines) - 1, 0)} rows; a log needs at least 10 "
                       "samples")
    try:
        data = np.loadtxt(lines[1:], delimiter=",", ndmin=2)
    except ValueError as exc:
        raise LogError(f"{path}: a row is not {len(cols)} numbers "
                       f"({' '.join(str(exc).split())[:120]}); fix or re-export the log") from None
    if data.shape[0] < 10:
        raise LogError(f"{path}: only {data.shape[0]} rows; a log needs at least 10 samples")
    if not np.all(np.isfinite(data)):
        row = int(np.argwhere(~np.isfinite(data))[0, 0]) + 2
        raise LogError(f"{path}:{row}: not a finite number; fix the row or cut the log there")
    if data.shape[1] != len(cols):
        raise LogError(f"{path}: rows have {data.shape[1]} numbers, the header names "
                       f"{len(cols)} columns; fix the header or re-export the log")
    big = np.abs(data) > MAX_LOG_ABS
    if big.any():  # 1e308 passed as finite and the twin wrote thousands of rows of nan
        row = int(np.argwhere(big)[0, 0]) + 2
        raise LogError(f"{path}:{row}: value beyond ±{MAX_LOG_ABS:g} (mm, s); fix the row or "
                       "cut the log there")
    t = data[:, cols.index("t")]
    dt = np.diff(t)
    ts = float(np.median(dt))
    if np.any(np.abs(dt - ts) > 0.01 * ts):
        row = int(np.argmax(np.abs(dt - ts) > 0.01 * ts)) + 3
        raise LogError(f"{path}:{row}: samples are not uniform (step {dt[row - 3]:.6g} s vs "
                       f"{ts:.6g} s); resample the log to a fixed period")
    check_log_period(str(path), ts)
    if abs(ts - ts_s) > 0.01 * ts_s:  # a 1 ms or 5 ms logger: onto the profile's grid
        (data,), how = resample_columns(ts, ts_s, data)
        t = data[0, cols.index("t")] + np.arange(data.shape[0]) * ts_s
        data[:, cols.index("t")] = t
        warnings.warn(f"{path}: sampled every {ts * 1000:.4g} ms, the profile's Ts is "
                      f"{ts_s * 1000:g} ms: resampled to it ({how})", LogWarning, stacklevel=2)
    get = {c: data[:, i] for i, c in enumerate(cols)}
    if planned:
        return t, get["x"], get["y"], None, None
    return t, get["x_cmd"], get["y_cmd"], get.get("x"), get.get("y")


def measured_in_machine_frame(prof, source, cmd_xy, cmd_in, xm, ym, w0):
    """The measured columns with a sensor offset subtracted, as ``load_log`` does for
    ``learn`` and ``diagnose`` (``closedloop.logs.remove_sensor_offsets``; its warnings)."""
    from ..closedloop.logs import MotionLog, remove_sensor_offsets, twin_mean_xy

    pred = twin_mean_xy(prof, cmd_in)
    z = np.zeros((len(xm), 1))
    log = MotionLog(ts_s=prof.ts_s, cmd_mm=np.hstack([cmd_xy, z]),
                    pos_mm=np.column_stack([xm, ym, z]), source=str(source), kind="encoder",
                    warmup=min(w0, len(xm)))
    log, notes = remove_sensor_offsets(log, pred)
    for note in notes:
        warnings.warn(note, LogWarning, stacklevel=2)
    return log.pos_mm[:, 0], log.pos_mm[:, 1]


@click.command("predict")
@click.argument("log", type=click.Path(dir_okay=False, path_type=pathlib.Path))
@click.option("--machine", "-m", required=True, help="Built-in profile or profile .yaml.")
@click.option("-o", "--output", required=True, type=click.Path(dir_okay=False, path_type=pathlib.Path),
              help="Write t,x_mean,x_std,y_mean,y_std here ('-' for stdout).")
@click.option("--no-learn", is_flag=True, help="Do not learn from the measured columns.")
def predict(log, machine, output, no_learn):
    """Predict the actual X/Y positions of LOG's commanded motion with the twin, learning online
    (one sample behind) from the measured columns x, y when the log has them. LOG may also be
    a plan written by `optimize --trajectory` (t,x,y,z,e). A profile's extensions written by
    `diagnose -o` are part of the prediction (docs/diagnose.md)."""
    # heavy stages imported on use: `gcode-feedopt --help` imports every command module
    from ..closedloop.logs import edge_speeds_mm_s, log_warmup
    from ..twin.model import axis_twin
    from ..twin.physics import machine_command

    prof = load_profile(machine)
    check_input(log)
    target = check_outputs({"-o": output}, inputs=[log, *profile_files(machine)])["-o"]
    t, xc, yc, xm, ym = read_log_columns(log, prof.ts_s)
    cmd_xy = np.column_stack([xc, yc])
    w0 = log_warmup(cmd_xy, prof.ts_s, prof)
    if w0:
        v0, _ = edge_speeds_mm_s(cmd_xy, prof.ts_s)
        warnings.warn(f"{log}: starts mid-motion (the command moves at {v0:.3g} mm/s at t=0): "
                      f"its first {min(w0, len(t))} samples ({w0 * prof.ts_s:.2f} s, the twin's "
                      f"memory) depend on motion before the log; they are predicted as if the "
                      f"machine had been at rest at the first row, not learned from, and left "
                      f"out of the summary", LogWarning, stacklevel=1)
    out = [t]
    summary = []
    # the twin acts on what the machine received: the commands through the input shaper
    cmd_in = machine_command(prof, cmd_xy)
    if xm is not None and ym is not None:  # the sensor's zero (closedloop.logs)
        xm, ym = measured_in_machine_frame(prof, log, cmd_xy, cmd_in, xm, ym, w0)
    off = mean_offsets(prof, cmd_in)
    for i, (axis, cmd, meas) in enumerate((("x", cmd_in[:, 0], xm), ("y", cmd_in[:, 1], ym))):
        tw = axis_twin(prof, axis)
        mean, std = tw.run(cmd, meas, learn=(meas is not None and not no_learn), warmup=w0,
                           offset_mm=off[:, i],
                           extra_var_mm2=extra_variance_mm2(prof.axes[axis].effects))
        out += [mean, std]
        if meas is not None and w0 < len(t):
            r = meas[w0:] - mean[w0:]
            inside = float(np.mean(np.abs(r) <= 1.959964 * std[w0:]))
            summary.append(f"{axis} RMS {np.sqrt(np.mean(r * r)) * 1e3:.2f} µm, 95 % interval "
                           f"holds {inside:.1%}")
    arr = np.column_stack(out)
    with output_file(target, text=True) as fh:
        fh.write("t,x_mean,x_std,y_mean,y_std\n")
        np.savetxt(fh, arr, fmt=["%.6f", "%.6f", "%.6f", "%.6f", "%.6f"], delimiter=",")
    click.echo(f"predict: {len(t)} samples -> {output}", err=True)
    if summary:
        span = f"samples {w0}-{len(t) - 1}" if w0 else "all samples"
        click.echo(f"predict: measured - predicted ({span}): " + "; ".join(summary), err=True)
