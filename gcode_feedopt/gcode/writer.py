"""Writers: a Schedule back into G-code.

*re-feedrated* (default): each original move is split into as few sub-moves as needed for
the F values to follow the planned speed within ``SPEED_TOL`` (relative, with a floor of
``SPEED_TOL_ABS_MM_S``); each sub-move's F is its average planned speed, so the time of every
piece — and of the file — is the plan's. E is split exactly in proportion to length (absolute
and relative E), each original move still ends at its original coordinates (the last piece
reuses the original number texts, or for relative moves the exact decimal remainder), arcs are
split into sub-arcs (G2/G3 with I/J recomputed), the modal F is restored before any untouched
motion line that relies on it, and no piece is shorter than 1/max_lines_per_s.

Where a slow-down plan (optimize.slowdown) runs a stretch at a lower acceleration than the
firmware's, the writer cuts the moves at the plan's cell runs and tells the firmware each
run's acceleration and junction rule (Marlin ``M204 P T`` and, when the file uses classic jerk,
``M205 X Y``; Klipper ``SET_VELOCITY_LIMIT ACCEL SQUARE_CORNER_VELOCITY``), restoring the
settings in force before the next line that is not a slowed piece or a comment and at the
end: the firmware then runs the plan itself, one line per run, instead of a staircase of F
values at full acceleration (which runs ~2 % slower than planned, with the acceleration bursts
the plan avoided).

Under ``--accel plan`` (firmware.accel_override) the plan runs at its own accelerations where
the file sets lower ones: right after each such line of the file (after the homing that follows
it, if any) one line sets the plan's again, and after the last move the file's own come back.

*sampled* (``mode="sampled"``): one G1 per Ts of the plan; a header comment states Ts.

Every other line passes through byte for byte. The writer returns, with the bytes, a tag for
each output line so :mod:`verify` can check the invariants independently.

This module walks the file's lines and decides what each becomes; the pieces of a re-timed
move (how many lines, at which F: ``SPEED_TOL`` and the rest) are gcode.pieces', their text is
gcode.motion_lines', and the lines that set the firmware's accelerations and give them back are
gcode.firmware_lines'. ``plan_peaks``, ``segment_times`` and ``single_piece_speeds`` are
importable from here too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import __version__
from ..firmware import override_restore_texts
from .firmware_lines import _AccelState, _ClampState, _PlanLimits, override_why
from .metadata import MetadataUpdater
from .motion_lines import _Emitter, _fmt
from .path import Path
from .pieces import (_cell_runs, _pieces, _run_pieces, _slowed_segments, _split_pieces,
                     plan_peaks, segment_times, single_piece_speeds)
from .reader import IDENT_PREFIX, Program
from .schedule import Schedule, SlowdownCells

# Tags of output lines.
T_ORIG, T_META, T_NEW, T_RESTORE, T_IDENT, T_ACCEL = 0, 1, 2, 3, 4, 5

#: what other modules import from here (plan_peaks, segment_times, single_piece_speeds live
#: in gcode.pieces)
__all__ = ["T_ACCEL", "T_IDENT", "T_META", "T_NEW", "T_ORIG", "T_RESTORE", "WriteResult",
           "plan_peaks", "segment_times", "single_piece_speeds", "write", "write_trajectory_csv"]


@dataclass
class WriteResult:
    data: bytes
    #: per output line: (tag, index) — input line index for T_ORIG/T_META, move index for T_NEW
    tags: list
    lines_written: int
    moves_changed: int
    sub_moves: int
    #: lines written to set and restore the firmware's acceleration around slowed stretches
    accel_lines: int = 0
    #: the lines that set the plan's limits on a printer configured lower (``_PlanLimits``)
    plan_limit_lines: tuple = ()
    #: lines re-setting the plan's acceleration after the file's lines that lower it, and
    #: giving the file's own back after the last move (``--accel plan``, firmware
    #: .AccelOverride)
    override_lines: int = 0


def _ending(line: bytes) -> bytes:
    if line.endswith(b"\r\n"):
        return b"\r\n"
    if line.endswith(b"\n"):
        return b"\n"
    return b""


def write(program: Program, path: Path, schedule: Schedule, profile, *, mode: str = "refeed",
          accel_mm_s2: np.ndarray | None = None, fast: bool = True,
          cells: SlowdownCells | None = None,
          settings=None, clamp=None, feed_cap_mm_s: np.ndarray | None = None,
          run_settings: str = "", override=None) -> WriteResult:
    """Write the re-timed G-code (see module docstring).

    ``cells`` (a slow-down plan's ``schedule.cells``, gcode.schedule.SlowdownCells: each
    cell's boundaries, segment, scale and the plan's limits in it) with ``settings``
    (firmware.Replay.accel_settings of the program): moves through slowed cells are cut at the
    cell runs and the firmware is told each run's acceleration (:class:`_AccelState`), in
    re-feedrated mode.

    ``clamp`` (firmware.Replay.accel_clamp of the program under the plan's axis limits, or None):
    where the file lets the firmware accelerate harder than the plan (``--amax``, a profile's
    lower limits), a line setting the plan's limits (Marlin ``M201 X Y Z``, Klipper
    ``SET_VELOCITY_LIMIT ACCEL``) goes before the first move concerned and again after any
    line of the file that sets them; the file's own values come back after the last move.

    ``accel_mm_s2``: (N,) the acceleration the firmware will use on each segment; where the
    plan follows the firmware's own trapezoid, one line with F = the plan's peak speed
    reproduces it, so no extra lines are written.

    ``override`` (firmware.accel_override, ``--accel plan``): right after each line of the
    file that sets an acceleration below the plan's (or after the homing that follows it), a
    line setting the plan's value again (Marlin ``M204 P.. T..`` / ``M201 X.. Y..``, Klipper
    ``SET_VELOCITY_LIMIT ACCEL=..``, with a ``; gcode-feedopt:`` comment); after the last move
    the file's own values in force there. ``settings`` and ``clamp`` are then those the
    override leaves in force, so slowed stretches and clamps restore the plan's values.

    ``run_settings``: what the run was made with, recorded in brackets on the ident line
    (pipeline.run_settings: ``batch`` re-processes an output whose settings differ).

    ``feed_cap_mm_s``: (N,) no line of segment k is written faster than this (the speed
    policy's ceiling, plan.speed.feed_ceiling; None: no cap).

    ``fast``: decide the moves that stay one line for all segments at once
    (:func:`single_piece_speeds`) and write them with :meth:`_Emitter.one_line`; every other
    move goes through :func:`_pieces` and :meth:`_Emitter.pieces_lines`. ``False`` sends every
    move through those two (the reference the fast path is tested against: same bytes)."""
    run = _Run(program, path, schedule, profile, mode=mode, accel_mm_s2=accel_mm_s2, fast=fast,
               cells=cells, settings=settings, clamp=clamp, feed_cap_mm_s=feed_cap_mm_s,
               run_settings=run_settings, override=override)
    for i, raw in enumerate(program.lines):
        run.line(i, raw)
    return run.finish()


class _Run:
    """One call of :func:`write`: what it decides before the first line (the speeds of the
    moves that stay one line, the slowed segments, the states of the firmware lines), the output
    so far, and what each line of the file becomes (:meth:`line`)."""

    def __init__(self, program: Program, path: Path, schedule: Schedule, profile, *, mode: str,
                 accel_mm_s2, fast: bool, cells, settings, clamp, feed_cap_mm_s,
                 run_settings: str, override):
        self.program, self.path, self.cells, self.override = program, path, cells, override
        self.accel_mm_s2 = accel_mm_s2
        self.sampled = sampled = mode == "sampled"
        fw = profile.firmware
        self.min_dt = 0.0 if sampled else 1.0 / fw.max_lines_per_s
        self.t_start, self.t_end = segment_times(schedule, path)
        self.s = schedule.s_mm
        self.ts = schedule.ts_s
        self.seg_of_move = {int(m): k for k, m in enumerate(path.move_index)}
        self.moves = moves = program.moves
        self.emitter = _Emitter(program, None if feed_cap_mm_s is None else {
            moves[int(m)].line_no: float(c) for m, c in zip(path.move_index, feed_cap_mm_s)})
        self.move_at_line = {mv.line_no: i for i, mv in enumerate(moves)}
        total_s = schedule.duration_s
        self.meta = MetadataUpdater(program, total_s)
        self.t_at_line = _times_at_lines(program, path, self.t_start, total_s)
        self.one_speed, self.peaks = _one_line_speeds(schedule, path, self.t_start, self.t_end,
                                                      accel_mm_s2, fast, sampled)
        self.acc_state = self.slowed = self.cell_range = None
        if cells is not None and settings is not None and not sampled:
            self.slowed, self.cell_range = _slowed_segments(cells, path.n_segments)
            if self.slowed is not None:
                self.acc_state = _AccelState(settings)
                if self.one_speed is not None:
                    for k in np.flatnonzero(self.slowed).tolist():
                        self.one_speed[k] = math.nan
        self.clamp_state = _ClampState(clamp) if clamp is not None else None
        self.plan_limits = (_PlanLimits(fw, settings)
                            if settings is not None and _PlanLimits.needed(fw, settings)
                            else None)
        self.ov_lines = override.lines if override is not None else {}
        self.n_override = 0
        self.last_new = -1  # index in ``out`` after the last re-timed line
        self.last_move = -1  # the last move (for the restores after it)
        self.out: list[bytes] = []
        self.tags: list = []
        self.first_ending = _ending(program.lines[0]) or b"\n"
        self.ident = (IDENT_PREFIX + f" {__version__}".encode()
                      + (f" (mode sampled, Ts = {self.ts * 1000:g} ms: one G1 per sample)".encode()
                         if sampled else b"")
                      + (f" [{run_settings}]".encode() if run_settings else b"")
                      + self.first_ending)
        self.cur_feed = 0.0  # modal F the firmware has from our output, mm/s
        self.moves_changed = 0
        self.sub_moves = 0

    def _end(self, raw: bytes) -> bytes:
        """The line ending of our lines written for (or before) ``raw``."""
        return _ending(raw) or self.first_ending

    def _accel(self, lines: list[bytes]) -> None:
        self.out.extend(lines)
        self.tags.extend([(T_ACCEL, -1)] * len(lines))

    def line(self, i: int, raw: bytes) -> None:
        """Write line ``i`` of the file (and the ident line after the first)."""
        if i == 1 or (i == 0 and len(self.program.lines) == 1):
            if i == 0:  # a file of one line: that line as it is, then the ident
                self.out.append(raw if raw.endswith(b"\n") else raw + self.first_ending)
                self.tags.append((T_ORIG, i))
                self.out.append(self.ident)
                self.tags.append((T_IDENT, -1))
                return
            self.out.append(self.ident)
            self.tags.append((T_IDENT, -1))
        mi = self.move_at_line.get(i)
        if self.acc_state is not None and self.acc_state.active is not None:
            self._end_slowed_stretch(raw, mi)
        if mi is None:
            self._other_line(i, raw)
            return
        self.last_move = mi
        if self.plan_limits is not None or self.clamp_state is not None:
            self._limits_before_move(raw, mi)
        mv = self.moves[mi]
        k = self.seg_of_move.get(mi)
        if k is None or mv.fixed:
            self._untouched_move(i, raw, mi, mv)
        elif self.slowed is not None and self.slowed[k]:
            self._slowed_move(raw, mi, mv, k)
        elif self.one_speed is not None and not math.isnan(self.one_speed[k]):
            self._one_line_move(raw, mi, mv, k)
        else:
            self._split_move(raw, mi, mv, k)

    def _end_slowed_stretch(self, raw: bytes, mi: int | None) -> None:
        """Back to the settings in force before anything but a slowed move or a comment."""
        k = self.seg_of_move.get(mi) if mi is not None else None
        keep = (k is not None and self.slowed[k] and not self.moves[mi].fixed) or (
            mi is None and raw.lstrip()[:1] in (b";", b""))
        if not keep:
            lines = self.acc_state.restore(self._end(raw))
            self._accel(lines)
            if (lines and self.clamp_state is not None and self.acc_state.restores_clamp
                    and mi is not None):
                self.clamp_state.set_to_want(mi)

    def _limits_before_move(self, raw: bytes, mi: int) -> None:
        """The plan's limits before the first re-timed move, the clamp's before any move."""
        plan_limits = self.plan_limits
        if (plan_limits is not None and not plan_limits.done
                and self.seg_of_move.get(mi) is not None and not self.moves[mi].fixed):
            self._accel(plan_limits.before_first(mi, self._end(raw)))
        if self.clamp_state is not None:
            self._accel(self.clamp_state.before_move(mi, self._end(raw)))

    def _retimed(self, mi: int, lines: list[bytes], feed_mm_s: float) -> None:
        self.out.extend(lines)
        self.tags.extend([(T_NEW, mi)] * len(lines))
        self.moves_changed += 1
        self.sub_moves += len(lines)
        self.cur_feed = feed_mm_s

    def _slowed_move(self, raw: bytes, mi: int, mv, k: int) -> None:
        """A move through slowed cells: one piece per cell run (or more), each run's
        acceleration line before its first piece (:class:`_AccelState`)."""
        path, acc_state = self.path, self.acc_state
        lo, hi = float(path.s0_mm[k]), float(path.s0_mm[k + 1])
        runs, vcap, vpk = _cell_runs(self.cells, self.cell_range, k, lo, hi)
        acc_k = 0.0 if self.accel_mm_s2 is None else float(self.accel_mm_s2[k])
        pieces, first = _run_pieces(self.s, self.ts, runs, lo, hi - lo, float(self.t_start[k]),
                                    float(self.t_end[k]), self.min_dt, acc_k, vcap, vpk)
        comment = _comment(raw)
        ending = self._end(raw)
        lines = self.emitter.pieces_lines(mv, pieces, ending, comment)
        starts = dict(zip(first, runs))
        for j, line in enumerate(lines):
            run = starts.get(j)
            if run is not None:
                self._accel(acc_state.restore(ending) if run[2] is None
                            else acc_state.set(run[2], mi, ending))
            self.out.append(line)
            self.tags.append((T_NEW, mi))
        self.last_new = len(self.out)
        self.moves_changed += 1
        self.sub_moves += len(lines)
        self.cur_feed = pieces[-1][1]

    def _one_line_move(self, raw: bytes, mi: int, mv, k: int) -> None:
        """A move the fast path left in one line (:func:`single_piece_speeds`)."""
        v = self.one_speed[k]
        comment = _comment(raw)
        # the most common line of all: written without _retimed's list
        self.out.append(self.emitter.one_line(mv, v, self._end(raw), comment))
        self.tags.append((T_NEW, mi))
        self.moves_changed += 1
        self.sub_moves += 1
        self.cur_feed = v

    def _split_move(self, raw: bytes, mi: int, mv, k: int) -> None:
        """Any other re-timed move: its pieces from the samples inside it."""
        s, path = self.s, self.path
        ta, tb = self.t_start[k], self.t_end[k]
        lo, hi = path.s0_mm[k], path.s0_mm[k + 1]
        j0 = np.searchsorted(s, lo, side="right")
        j1 = np.searchsorted(s, hi, side="left")
        inner_s = s[j0:j1]
        inner_t = np.arange(j0, j1) * self.ts
        L = hi - lo
        u_pts = np.concatenate([[0.0], (inner_s - lo) / L, [1.0]])
        t_pts = np.concatenate([[ta], inner_t, [tb]])
        comment = _comment(raw)
        ending = self._end(raw)
        if self.one_speed is not None and not self.sampled:
            # NaN from the fast path: samples inside the segment and no single line
            # reproduces them (_firmware_band refused it, or there is no accel)
            pieces = _split_pieces(u_pts, t_pts, L, self.min_dt)
            lines = self.emitter.split_lines(mv, pieces, ending, comment)
        else:
            acc_k = 0.0 if self.accel_mm_s2 is None else float(self.accel_mm_s2[k])
            if self.peaks is not None and not math.isnan(self.peaks[k]):
                pieces = [(1.0, self.peaks[k])]
            else:
                pieces = _pieces(u_pts, t_pts, L, self.min_dt, self.sampled, acc_k)
            lines = self.emitter.pieces_lines(mv, pieces, ending, comment)
        self._retimed(mi, lines, pieces[-1][1])

    def _untouched_move(self, i: int, raw: bytes, mi: int, mv) -> None:
        """A motion line left as it is, after the modal F it relies on if ours changed it."""
        cur_feed = self.cur_feed
        if "F" not in mv.words and abs(cur_feed - mv.feed_mm_s) > 1e-9 and cur_feed > 0:
            self.out.append(f"G1 F{_fmt(mv.feed_mm_s * 60.0, 4)}".encode() + self._end(raw))
            self.tags.append((T_RESTORE, mi))
        self.out.append(raw)
        self.tags.append((T_ORIG, i))
        self.cur_feed = mv.feed_mm_s

    def _other_line(self, i: int, raw: bytes) -> None:
        """A line that does not move: its metadata updated (time, progress) or as it is, then
        the plan's accelerations again if it lowers them (``--accel plan``)."""
        new = self.meta.update(i, raw, self.t_at_line[i])
        if new is not None:
            self.out.append(new)
            self.tags.append((T_META, i))
        else:
            self.out.append(raw)
            self.tags.append((T_ORIG, i))
        if i in self.ov_lines and _ending(raw):
            # the file lowers an acceleration below the plan's: the plan's again
            for text in self.ov_lines[i]:
                self.out.append(text.encode() + override_why(text) + _ending(raw))
                self.tags.append((T_ACCEL, -1))
            self.n_override += len(self.ov_lines[i])
        f_word = _feed_only(raw)
        if f_word is not None:
            self.cur_feed = f_word

    def _insert(self, at: int, lines: list[bytes]) -> None:
        self.out[at:at] = lines
        self.tags[at:at] = [(T_ACCEL, -1)] * len(lines)

    def finish(self) -> WriteResult:
        """After the last line: what our lines changed given back after the last move (the
        clamp, a slowed stretch the file ends in, ``--accel plan``, the plan's limits: each
        after the last motion line and the restores before it), and the result."""
        first_ending, last = self.first_ending, self.last_move
        accel_lines = 0
        if self.clamp_state is not None and last >= 0:
            # the file's own limits back right after the last motion line
            at = _after_move_line(self.tags, last, self.moves[last].line_no)
            self._insert(at, self.clamp_state.restore(last, first_ending))
            accel_lines += self.clamp_state.lines
        if self.acc_state is not None:
            # the file ends in a slowed stretch (then comments): restore right after it
            self._insert(self.last_new, self.acc_state.restore(first_ending))
            accel_lines += self.acc_state.lines
        if self.override is not None and self.override.restore and last >= 0:
            # the file's own accelerations back after the last motion line and what restores
            # the slowed stretches' settings and the clamp there
            at = _after_last_move(self.tags, last, self.moves[last].line_no)
            lines = [t.encode() + override_why(t, restore=True) + first_ending
                     for t in override_restore_texts(self.override)]
            self._insert(at, lines)
            self.n_override += len(lines)
        accel_lines += self.n_override
        plan_limits = self.plan_limits
        if plan_limits is not None and plan_limits.done and last >= 0:
            # the printer's configured limits back after the last motion line and what
            # restores the file's own and the slowed stretches' settings there
            at = _after_last_move(self.tags, last, self.moves[last].line_no)
            self._insert(at, plan_limits.restore(first_ending))
            accel_lines += plan_limits.lines
        return WriteResult(data=b"".join(self.out), tags=self.tags, lines_written=len(self.out),
                           moves_changed=self.moves_changed, sub_moves=self.sub_moves,
                           accel_lines=accel_lines,
                           plan_limit_lines=(plan_limits.set_lines if plan_limits is not None
                                             else ()),
                           override_lines=self.n_override)


def _times_at_lines(program: Program, path: Path, t_start: np.ndarray, total_s: float) -> list:
    """Elapsed time at each line of the file: the start of the next segment's motion after it
    (the end of the print after the last), s."""
    moves = program.moves
    seg_lines = np.array([moves[int(m)].line_no for m in path.move_index], dtype=np.int64)
    k_next = np.searchsorted(seg_lines, np.arange(len(program.lines)), side="right")
    return (np.where(k_next < t_start.size, t_start[np.minimum(k_next, t_start.size - 1)],
                     total_s) if t_start.size else np.full(k_next.size, total_s)).tolist()


def _one_line_speeds(schedule: Schedule, path: Path, t_start: np.ndarray, t_end: np.ndarray,
                     accel_mm_s2, fast: bool, sampled: bool):
    """(N,) list, the speed of each segment the writer leaves in one line, NaN for the others
    (None unless ``fast``): :func:`single_piece_speeds`, and the plan's own peak where it says
    the segment is one firmware trapezoid; and (N,) list, that peak, NaN elsewhere (None
    when the plan does not say or in sampled mode; :func:`plan_peaks`)."""
    one_speed = (single_piece_speeds(schedule.s_mm, schedule.ts_s, path.s0_mm, t_start, t_end,
                                     accel_mm_s2, sampled) if fast else None)
    peaks = None if sampled else plan_peaks(schedule, accel_mm_s2, path.n_segments)
    if one_speed is not None:
        if peaks is not None:
            one_speed = np.where(np.isnan(peaks), one_speed, peaks)
        one_speed = one_speed.tolist()
    if peaks is not None:
        peaks = peaks.tolist()
    return one_speed, peaks


def _comment(raw: bytes) -> bytes:
    """The comment of a motion line (from its ``;``, without the line ending), or b""."""
    semi = raw.find(b";")
    return raw[semi:].rstrip(b"\r\n") if semi >= 0 else b""


def _after_move_line(tags: list, last_move: int, last_line: int) -> int:
    """Index in the output right after the last motion line (re-timed or left as it is)."""
    at = len(tags)
    while at > 0 and not (tags[at - 1] == (T_NEW, last_move)
                          or tags[at - 1] == (T_ORIG, last_line)):
        at -= 1
    return at


def _after_last_move(tags: list, last_move: int, last_line: int) -> int:
    """Index in the output after the last motion line and the lines of ours that follow it."""
    at = _after_move_line(tags, last_move, last_line)
    while at < len(tags) and tags[at] == (T_ACCEL, -1):
        at += 1
    return at


def _feed_only(raw: bytes) -> float | None:
    """F of a `G0/G1 F...` line without axes (modal feed set), mm/s; else None."""
    text = raw.split(b";", 1)[0].strip().upper()
    if not text.startswith((b"G1", b"G0")) or b"F" not in text:
        return None
    toks = text.split()
    if toks[0] not in (b"G1", b"G0", b"G01", b"G00"):
        return None
    f = None
    for t in toks[1:]:
        if t[:1] in (b"X", b"Y", b"Z", b"E"):
            return None
        if t[:1] == b"F":
            try:
                f = float(t[1:]) / 60.0
            except ValueError:
                return None
    return f


def write_trajectory_csv(fh, schedule: Schedule, path: Path) -> None:
    """``t,x,y,z,e`` per sample of the plan (s, mm)."""
    s = schedule.s_mm
    pos = path.position(s)
    k = path.segment_at(s)
    L = path.length_mm[k]
    u = np.where(L > 0, (s - path.s0_mm[k]) / np.where(L > 0, L, 1.0), 0.0)
    e_start = np.concatenate([[0.0], np.cumsum(path.de_mm)])[:-1]
    e = e_start[k] + path.de_mm[k] * np.clip(u, 0, 1)
    t = np.arange(s.size) * schedule.ts_s
    arr = np.column_stack([t, pos, e])
    fh.write(b"t,x,y,z,e\n")
    np.savetxt(fh, arr, fmt=["%.4f", "%.5f", "%.5f", "%.5f", "%.5f"], delimiter=",")
