"""Encoder logs: the CSV the virtual machine writes and the closed loop reads.

Format: a header line naming ``t,x_cmd,y_cmd,x,y`` and optionally any of ``z_cmd,z,e_cmd``,
in any order (``write_log`` writes them in that order), then one row per sample period Ts;
seconds and millimetres, plain decimals (6 places: 1 nm, 1 µs). ``x_cmd``.. are the commanded
positions, ``x``.. the measured ones. A log whose times jitter, or that lost a sample or two,
is read on a uniform grid (``_on_uniform_grid``, with a ``LogWarning``).

Writing millions of rows with ``np.savetxt`` takes tens of seconds (one Python ``%`` per
value); ``write_log`` formats a whole block of rows at once with integer arithmetic on a byte
matrix, and ``read_log`` parses with ``np.fromstring`` after checking the header (see
``benchmarks/bench_simulate.py`` for both speeds).
"""

from __future__ import annotations

import difflib
import os
import warnings
from dataclasses import dataclass

import numpy as np

from ..errors import LogError, LogWarning
from ..outputs import output_file
from .trajectory import Trajectory

REQUIRED_COLUMNS = ("t", "x_cmd", "y_cmd", "x", "y")
OPTIONAL_COLUMNS = ("z_cmd", "z", "e_cmd")
DECIMALS = 6
#: Rows formatted per block (8 columns: a ~10 MB byte matrix; measured faster than 1 << 19).
_BLOCK_ROWS = 1 << 16
#: Sample times may deviate from a uniform grid by this fraction of Ts (float round-off of
#: a printed 6-decimal time) and the rows are read as they are.
TS_JITTER = 1e-3
#: Beyond that, a log's steps may lie between JITTER_MIN and GAP_MAX times its median step
#: (jitter; a sample or two dropped): it is read on a uniform grid (``_on_uniform_grid``).
JITTER_MIN = 0.5
GAP_MAX = 3.5


@dataclass(frozen=True)
class EncoderLog:
    """An encoder log.

    Attributes:
        t_s: shape (K,). Sample times, s (uniform, Ts apart).
        cmd_mm: shape (K, 3). Commanded X, Y, Z, mm (Z = 0 when the log has no z_cmd).
        pos_mm: shape (K, 3). Measured X, Y, Z, mm (Z = 0 when the log has no z).
        e_cmd_mm: shape (K,) commanded filament position, mm, or None.
        columns: the header's column names in order.
    """

    t_s: np.ndarray
    cmd_mm: np.ndarray
    pos_mm: np.ndarray
    e_cmd_mm: np.ndarray | None
    columns: tuple[str, ...]

    @property
    def ts_s(self) -> float:
        """Sample period, s."""
        return float((self.t_s[-1] - self.t_s[0]) / (self.t_s.size - 1))

    def trajectory(self) -> Trajectory:
        """The commanded motion as a Trajectory (E = 0 when the log has no e_cmd)."""
        e = self.e_cmd_mm if self.e_cmd_mm is not None else np.zeros(self.t_s.size)
        return Trajectory(ts_s=self.ts_s, pos_mm=self.cmd_mm, e_mm=e)


#: "000".."999" as bytes, shape (1000, 3): digits are written three at a time.
_DIGITS3 = np.array([list(f"{i:03d}".encode()) for i in range(1000)], dtype=np.uint8)


def format_rows(values: np.ndarray, decimals: int = DECIMALS) -> bytes:
    """Shape (R, C) floats -> CSV bytes, ``decimals`` places (a multiple of 3), rows ending
    in ``\n``; the same text as ``f"{v:.6f}"`` except that -0.000000 is written 0.000000.

    Vectorised: each value becomes a fixed-width field of a uint8 matrix, digits three at a
    time from a table, leading zeros blanked to 0 bytes, and the 0 bytes dropped at the end.
    """
    if decimals % 3 or decimals <= 0:
        raise ValueError(f"decimals={decimals} must be a positive multiple of 3")
    v = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(v)):
        raise ValueError("cannot write NaN or infinite values to a log")
    R, C = v.shape
    scale = 10 ** decimals
    n = np.rint(v * scale).astype(np.int64)
    neg = n < 0
    ip, fp = np.divmod(np.abs(n), scale)
    n_int = len(str(int(ip.max()))) if ip.size else 1
    n_grp = -(-n_int // 3)
    n_int_field = 3 * n_grp
    width = 1 + n_int_field + 1 + decimals + 1  # sign, integer digits, dot, fraction, separator
    buf = np.empty((R, C, width), dtype=np.uint8)
    buf[:, :, 0] = 0
    buf[:, :, -1] = ord(",")
    buf[:, -1, -1] = ord("\n")
    buf[:, :, -2 - decimals] = ord(".")
    q = fp
    for g in range(decimals // 3):  # fraction, right to left
        q, d = np.divmod(q, 1000)
        end = width - 1 - 3 * g
        buf[:, :, end - 3:end] = _DIGITS3[d]
    q = ip
    for g in range(n_grp):  # integer part, right to left
        q, d = np.divmod(q, 1000)
        end = width - 2 - decimals - 3 * g
        buf[:, :, end - 3:end] = _DIGITS3[d]
    # digit i of the integer part (0 = units) sits at column width - 3 - decimals - i; blank
    # the leading zeros (i >= number of digits) and put the sign just left of the first digit
    ndig = np.ones(ip.shape, dtype=np.int8)
    for i in range(1, n_int_field):
        ndig += ip >= 10 ** i
    for i in range(1, n_int_field + 1):
        col = buf[:, :, width - 3 - decimals - i]
        col *= ndig > i
        col += np.uint8(ord("-")) * (neg & (ndig == i))
    flat = buf.reshape(-1)
    return flat[flat != 0].tobytes()


def write_log(path, t_s: np.ndarray, cmd_mm: np.ndarray, pos_mm: np.ndarray,
              e_cmd_mm: np.ndarray | None = None, include_z: bool = True) -> None:
    """Write an encoder log: ``t,x_cmd,y_cmd,x,y`` then ``z_cmd,z`` (if ``include_z``) and
    ``e_cmd`` (if given). Arrays: t (K,), cmd and pos (K, 3), e (K,). ``path``: a path or
    an ``outputs.Target`` (written through gcode_feedopt.outputs)."""
    t = np.asarray(t_s, dtype=float)
    cmd = np.asarray(cmd_mm, dtype=float)
    pos = np.asarray(pos_mm, dtype=float)
    cols = [t, cmd[:, 0], cmd[:, 1], pos[:, 0], pos[:, 1]]
    names = list(REQUIRED_COLUMNS)
    if include_z:
        cols += [cmd[:, 2], pos[:, 2]]
        names += ["z_cmd", "z"]
    if e_cmd_mm is not None:
        cols.append(np.asarray(e_cmd_mm, dtype=float))
        names.append("e_cmd")
    K = t.size
    if any(c.shape != (K,) for c in cols):
        raise ValueError("write_log: every column must have as many samples as t")
    data = np.column_stack(cols)

    with output_file(path, "--log") as f:
        f.write((",".join(names) + "\n").encode())
        for r0 in range(0, K, _BLOCK_ROWS):
            f.write(format_rows(data[r0:r0 + _BLOCK_ROWS]))


def read_log(path) -> EncoderLog:
    """Read an encoder log. Raises LogError (what, where, the fix) on a malformed file."""
    name = os.fspath(path)
    try:
        with open(name, "rb") as f:
            raw = f.read()
    except OSError as exc:
        raise LogError(f"{name}: cannot read the log ({exc.strerror})") from None
    head, _, body = raw.partition(b"\n")
    try:
        header = head.decode("ascii").strip().lstrip("\ufeff")
    except UnicodeDecodeError:
        raise LogError(f"{name}:1: the header is not ASCII text; an encoder log starts with "
                       f"{','.join(REQUIRED_COLUMNS)}") from None
    columns = tuple(c.strip() for c in header.split(","))
    missing = [c for c in REQUIRED_COLUMNS if c not in columns]
    if missing:
        hint = ""
        if header.startswith("#time"):
            hint = " (this looks like a raw Klipper accelerometer file, not an encoder log)"
        raise LogError(f"{name}:1: header {header[:60]!r} lacks column(s) "
                       f"{','.join(missing)}; an encoder log's header names "
                       f"{','.join(REQUIRED_COLUMNS)} (any order){hint}")
    for c in columns:
        if c not in REQUIRED_COLUMNS and c not in OPTIONAL_COLUMNS:
            known = REQUIRED_COLUMNS + OPTIONAL_COLUMNS
            close = difflib.get_close_matches(c, known, n=1)
            did = f" (did you mean {close[0]!r}?)" if close else ""
            raise LogError(f"{name}:1: unknown column {c!r}{did}; a log's columns are "
                           f"{','.join(REQUIRED_COLUMNS)} and optionally "
                           f"{','.join(OPTIONAL_COLUMNS)}, in any order")
    if len(set(columns)) != len(columns):
        raise LogError(f"{name}:1: a column appears twice in {header!r}")
    C = len(columns)
    text = body.replace(b"\r", b"").strip(b"\n")
    n_rows = text.count(b"\n") + 1 if text else 0
    try:
        flat = np.fromstring(text.replace(b"\n", b",").decode("ascii"), dtype=float, sep=",") if text else np.empty(0)
    except (ValueError, UnicodeDecodeError):
        flat = None
    if flat is None or flat.size != n_rows * C:
        _raise_bad_row(name, text, C)
    data = flat.reshape(n_rows, C)
    if n_rows < 2:
        raise LogError(f"{name}: {n_rows} data rows; a log needs at least 2 (was it truncated?)")
    if not np.all(np.isfinite(data)):
        r = int(np.flatnonzero(~np.all(np.isfinite(data), axis=1))[0])
        raise LogError(f"{name}:{r + 2}: a value is NaN or infinite")
    t = data[:, columns.index("t")]
    dt = np.diff(t)
    ts = (t[-1] - t[0]) / (n_rows - 1)
    if ts <= 0 or np.any(np.abs(dt - ts) > TS_JITTER * ts + 10.0 ** -DECIMALS):
        data = _on_uniform_grid(name, data, columns.index("t"),
                                [columns.index(c) for c in ("x_cmd", "y_cmd")])
        t = data[:, columns.index("t")]
    col = {c: data[:, i] for i, c in enumerate(columns)}
    zeros = np.zeros(data.shape[0])
    cmd = np.column_stack([col["x_cmd"], col["y_cmd"], col.get("z_cmd", zeros)])
    pos = np.column_stack([col["x"], col["y"], col.get("z", zeros)])
    return EncoderLog(t_s=t, cmd_mm=cmd, pos_mm=pos, e_cmd_mm=col.get("e_cmd"), columns=columns)


def _on_uniform_grid(name: str, data: np.ndarray, it: int, icmd: list) -> np.ndarray:
    """The rows ``data`` (K, C) of a log whose times (column ``it``) are not uniform, on the
    uniform grid t₀ + k·Ts (Ts: the slope of the times against each row's place on the grid,
    to 1 µs), every column linearly interpolated there from the clock the commands (columns
    ``icmd``) run smoothly in (``_stamps_are_sample_times``); a ``LogWarning`` says which. A
    logger polled by a host has jitter, and a busy one drops a sample now and then; values
    taken at the stamped times but read as uniform rows err by v·δt (150 mm/s × 0.2 ms:
    30 µm), stamps of a timer's samples read as sample times err as much the other way.

    Refused (``LogError`` naming the row): a time that does not increase, a step below
    ``JITTER_MIN``·Ts (two clocks interleaved, or a resampled log), and a gap above
    ``GAP_MAX``·Ts (lost motion: no interpolation recovers a mode's swing across it)."""
    t, cmd = data[:, it], data[:, icmd]
    dt = np.diff(t)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        r = int(back[0])
        raise LogError(f"{name}:{r + 3}: time {t[r + 1]:.6g} s does not follow {t[r]:.6g} s on "
                       f"the row before; a log's t increases row by row (sort the file, or "
                       f"drop repeated rows)")
    ts = float(np.median(dt))
    if round(ts, DECIMALS) <= 0:
        raise LogError(f"{name}: the time steps' median is {ts:.3g} s: t is "
                       f"written with too few decimals (write seconds to 1 µs)")
    short = np.flatnonzero(dt < JITTER_MIN * ts)
    if short.size:
        r = int(short[0])
        raise LogError(f"{name}:{r + 3}: time step {dt[r]:.6g} s, the log's usual step is "
                       f"{ts:.6g} s; a log has one row per sample period (two loggers "
                       f"interleaved, or rows resampled?)")
    # each row's place on the grid (step by step: a lost sample is a step of two), then the
    # period as the slope through all of them: the median of jittered steps is off by
    # ~σ/√K, which adds up to whole samples over a long log
    n = np.concatenate(([0.0], np.cumsum(np.maximum(np.round(dt / ts), 1.0))))
    ts = round(float(np.polyfit(n, t, 1)[0]), DECIMALS)
    gaps = np.flatnonzero(dt > GAP_MAX * ts)
    if gaps.size:
        r = int(gaps[0])
        raise LogError(f"{name}:{r + 3}: a gap of {dt[r] * 1e3:.4g} ms after t={t[r]:.6g} s "
                       f"(the log's step is {ts * 1e3:.4g} ms): samples were lost there; "
                       f"split the file at that row: each piece is a usable log")
    placed = t[0] + n * ts
    at_times = _stamps_are_sample_times(t, placed, cmd)
    k = int(round(n[-1])) + 1
    grid = t[0] + np.arange(k) * ts
    src = t if at_times else placed
    out = np.column_stack([grid if j == it else np.interp(grid, src, data[:, j])
                           for j in range(data.shape[1])])
    off = np.abs(t - placed)
    lost = int(n[-1]) - (t.size - 1)
    how = ("every column interpolated on that grid at the logged times (the commands run "
           "smoothly in them)" if at_times else
           "the rows taken as that grid's samples (the commands run smoothly row by row, not "
           "in the logged times: the times are stamps of uniform samples)"
           + (", the missing ones interpolated" if lost else ""))
    warnings.warn(f"{name}: sample times are not uniform (steps {dt.min() * 1e3:.4g}–"
                  f"{dt.max() * 1e3:.4g} ms, up to {off.max() * 1e3:.3g} ms off a "
                  f"{ts * 1e3:.4g} ms grid" + (f", {lost} sample(s) missing" if lost else "")
                  + f"): {how}", LogWarning, stacklevel=3)
    return out


def _stamps_are_sample_times(t: np.ndarray, placed: np.ndarray, cmd: np.ndarray) -> bool:
    """Whether the commanded positions ``cmd`` (K, c) were sampled at the logged times ``t``
    (a logger that polls when it can) rather than on the uniform grid ``placed`` with late or
    early stamps (a logger that stamps what a timer sampled). A planner's command is smooth in
    its true time: each interior sample is predicted from its two neighbours by linear
    interpolation in either clock, and the clock with the smaller squared misfit wins (ties,
    e.g. a log that never moves, keep the logged times)."""
    def misfit(tt):
        w = (tt[1:-1] - tt[:-2]) / (tt[2:] - tt[:-2])
        mid = cmd[:-2] + w[:, None] * (cmd[2:] - cmd[:-2])
        return float(np.sum((cmd[1:-1] - mid) ** 2))
    if t.size < 3:
        return True
    return misfit(t) <= misfit(placed)


def _raise_bad_row(name: str, text: bytes, n_cols: int):
    """Find the first malformed row (slow path, only on error) and raise LogError."""
    for i, line in enumerate(text.split(b"\n")):
        parts = line.split(b",")
        if len(parts) != n_cols:
            raise LogError(f"{name}:{i + 2}: {len(parts)} values, the header has {n_cols}")
        try:
            [float(p) for p in parts]
        except ValueError:
            raise LogError(f"{name}:{i + 2}: {line[:60].decode('ascii', 'replace')!r} is not "
                           "a row of numbers") from None
    raise LogError(f"{name}: cannot parse the log body")
