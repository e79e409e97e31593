"""The text of the motion lines the writer writes for a re-timed move.

:class:`_Emitter` formats the pieces of one original move (the writer decides them) as
G0/G1/G2/G3 lines: intermediate points at ``XYZ_DECIMALS``/``E_DECIMALS`` (or the file's own
precision where it writes more), the last piece ending on the move's own number texts (for
relative moves the exact decimal remainder), arcs as sub-arcs with I/J recomputed, and F the
piece's speed under the speed policy's ceiling. The writer's other lines (gcode.firmware_lines)
use the same number formatting (``_fmt``).
"""

from __future__ import annotations

import math
from decimal import Decimal

import numpy as np

from .reader import Program

#: Decimals written for XYZ of intermediate points (0.1 µm) and at least for E.
XYZ_DECIMALS = 4
E_DECIMALS = 5
#: No F below this is written (a piece at the very start of an acceleration from rest);
#: 6 mm/min, below which firmware treat the feed as invalid or take forever.
MIN_FEED_MM_S = 0.1


def _decimals(text: str) -> int:
    text = text.lower().split("e")[0] if "e" in text.lower() and not text[0].isalpha() else text
    return len(text.split(".", 1)[1]) if "." in text else 0


def _fmt(v: float, nd: int) -> str:
    s = f"{v:.{nd}f}"
    if "." in s:
        s = s.rstrip("0").rstrip(".")
    if s in ("-0", ""):
        s = "0"
    return s


def _dec(d: Decimal) -> str:
    """A Decimal as plain text without exponent or trailing zeros."""
    t = format(d, "f")
    if "." in t:
        t = t.rstrip("0").rstrip(".")
    return "0" if t in ("-0", "") else t


def _fmt_feed(v_mm_s: float) -> str:
    return _fmt(max(v_mm_s, MIN_FEED_MM_S) * 60.0, 1)


class _Emitter:
    """Formats the sub-moves of one original move."""

    def __init__(self, program: Program, cap_by_line: dict | None = None):
        self.program = program
        #: line number -> the highest feed the move may be written at, mm/s (the speed
        #: policy's ceiling, plan.speed): the sample-based piece speeds can overshoot the
        #: plan's by a few % at a junction (segment times interpolated within a sample)
        self.cap_by_line = cap_by_line or {}

    def _feed(self, mv, v_mm_s: float) -> str:
        return _fmt_feed(min(v_mm_s, self.cap_by_line.get(mv.line_no, math.inf)))

    def pieces_lines(self, mv, pieces, ending: bytes, comment: bytes) -> list[bytes]:
        words = mv.words
        axes_present = [L for L in "XYZ" if L in words]
        has_e = "E" in words
        nd = {L: max(XYZ_DECIMALS, _decimals(words[L])) for L in axes_present}
        nd_e = max(E_DECIMALS, _decimals(words["E"])) if has_e else E_DECIMALS
        off = mv.offset_mm
        start = np.asarray(mv.start_mm)
        end = np.asarray(mv.end_mm)
        arc = mv.arc
        out = []
        written_sum = {L: Decimal(0) for L in "XYZE"}
        prev_pt = start.copy()
        n = len(pieces)
        for j, (u, v) in enumerate(pieces):
            last = j == n - 1
            if arc is None:
                pt = start + (end - start) * u
            else:
                th = math.atan2(start[1] - arc.center_mm[1], start[0] - arc.center_mm[0]) + arc.sweep_rad * u
                pt = np.array([arc.center_mm[0] + arc.radius_mm * math.cos(th),
                               arc.center_mm[1] + arc.radius_mm * math.sin(th),
                               start[2] + (end[2] - start[2]) * u])
            e = mv.e_start_mm + mv.de_mm * u
            parts = [mv.code]
            for k, L in enumerate("XYZ"):
                if L not in axes_present:
                    continue
                if last:
                    if mv.xyz_relative:
                        parts.append(f"{L}{_dec(Decimal(words[L]) - written_sum[L])}")
                    else:
                        parts.append(f"{L}{words[L]}")
                else:
                    if mv.xyz_relative:
                        # relative: delta from the previous *written* point, exact decimals
                        target = Decimal(_fmt(pt[k] - start[k], nd[L]))
                        delta = target - written_sum[L]
                        written_sum[L] += delta
                        txt = _fmt(float(delta), nd[L])
                    else:
                        txt = _fmt(pt[k] - off[k], nd[L])
                    parts.append(f"{L}{txt}")
            if arc is not None:
                cx, cy = arc.center_mm
                parts.append(f"I{_fmt(cx - prev_pt[0], 4)}")
                parts.append(f"J{_fmt(cy - prev_pt[1], 4)}")
            if has_e:
                if last:
                    if mv.e_relative:
                        parts.append(f"E{_dec(Decimal(words['E']) - written_sum['E'])}")
                    else:
                        parts.append(f"E{words['E']}")
                else:
                    if mv.e_relative:
                        target = Decimal(_fmt(e - mv.e_start_mm, nd_e))
                        delta = target - written_sum["E"]
                        written_sum["E"] += delta
                        parts.append(f"E{_fmt(float(delta), nd_e)}")
                    else:
                        parts.append(f"E{_fmt(e - off[3], nd_e)}")
            parts.append(f"F{self._feed(mv, v)}")
            line = " ".join(parts).encode("ascii")
            if j == 0 and comment:
                line += b" " + comment
            out.append(line + ending)
            prev_pt = pt
        return out


    def split_lines(self, mv, pieces, ending: bytes, comment: bytes) -> list[bytes]:
        """:meth:`pieces_lines` (the same lines) with the intermediate points of a straight
        move computed on Python floats, start + (end − start)·u per axis, which is the numpy
        expression's arithmetic element by element; arcs go to :meth:`pieces_lines`."""
        if mv.arc is not None:
            return self.pieces_lines(mv, pieces, ending, comment)
        words = mv.words
        axes = [(k, L) for k, L in enumerate("XYZ") if L in words]
        has_e = "E" in words
        nd = {L: max(XYZ_DECIMALS, _decimals(words[L])) for _, L in axes}
        nd_e = max(E_DECIMALS, _decimals(words["E"])) if has_e else E_DECIMALS
        off = mv.offset_mm
        start = mv.start_mm
        end = mv.end_mm
        rel = mv.xyz_relative
        written_sum = {L: Decimal(0) for L in "XYZE"}
        out = []
        n = len(pieces)
        for j, (u, v) in enumerate(pieces):
            last = j == n - 1
            parts = [mv.code]
            for k, L in axes:
                if last:
                    parts.append(f"{L}{_dec(Decimal(words[L]) - written_sum[L])}" if rel
                                 else f"{L}{words[L]}")
                    continue
                p = start[k] + (end[k] - start[k]) * u
                if rel:
                    target = Decimal(_fmt(p - start[k], nd[L]))
                    delta = target - written_sum[L]
                    written_sum[L] += delta
                    txt = _fmt(float(delta), nd[L])
                else:
                    txt = _fmt(p - off[k], nd[L])
                parts.append(f"{L}{txt}")
            if has_e:
                if last:
                    parts.append(f"E{_dec(Decimal(words['E']) - written_sum['E'])}"
                                 if mv.e_relative else f"E{words['E']}")
                else:
                    e = mv.e_start_mm + mv.de_mm * u
                    if mv.e_relative:
                        target = Decimal(_fmt(e - mv.e_start_mm, nd_e))
                        delta = target - written_sum["E"]
                        written_sum["E"] += delta
                        parts.append(f"E{_fmt(float(delta), nd_e)}")
                    else:
                        parts.append(f"E{_fmt(e - off[3], nd_e)}")
            parts.append(f"F{self._feed(mv, v)}")
            line = " ".join(parts).encode("ascii")
            if j == 0 and comment:
                line += b" " + comment
            out.append(line + ending)
        return out

    def one_line(self, mv, v_mm_s: float, ending: bytes, comment: bytes) -> bytes:
        """The line :meth:`pieces_lines` writes for a move left in one piece at ``v_mm_s``
        (``pieces_lines(mv, [(1.0, v_mm_s)], ...)[0]``), without its per-piece geometry: the
        move's own word texts (relative ones re-formatted as the last piece's exact
        remainder is), I/J from its start, and the new F."""
        words = mv.words
        parts = [mv.code]
        for L in "XYZ":
            if L in words:
                parts.append(f"{L}{_dec(Decimal(words[L]) - Decimal(0))}" if mv.xyz_relative
                             else f"{L}{words[L]}")
        arc = mv.arc
        if arc is not None:
            cx, cy = arc.center_mm
            parts.append(f"I{_fmt(cx - mv.start_mm[0], 4)}")
            parts.append(f"J{_fmt(cy - mv.start_mm[1], 4)}")
        if "E" in words:
            parts.append(f"E{_dec(Decimal(words['E']) - Decimal(0))}" if mv.e_relative
                         else f"E{words['E']}")
        parts.append(f"F{self._feed(mv, v_mm_s)}")
        line = " ".join(parts).encode("ascii")
        if comment:
            line += b" " + comment
        return line + ending
