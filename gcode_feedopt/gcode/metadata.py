"""Print-time metadata rewritten to the new estimate.

- Cura: ``;TIME:<s>`` (total) and ``;TIME_ELAPSED:<s>`` (at each layer end);
- PrusaSlicer / SuperSlicer / OrcaSlicer: ``; estimated printing time (normal mode) = 1h 2m 3s``
  (and ``(silent mode)``), and progress lines ``M73 P<percent> R<minutes left>`` /
  ``M73 Q<percent> S<minutes left>`` (silent mode). We model one machine mode, so silent-mode
  lines get the same figures as normal mode.

The line ending and anything after the value (a comment) are kept.
"""

from __future__ import annotations

import re

_TIME = re.compile(rb"^;TIME:\s*[-+\d.]+")
_ELAPSED = re.compile(rb"^;TIME_ELAPSED:\s*[-+\d.]+")
_EST = re.compile(rb"^(;\s*estimated printing time \((?:normal|silent) mode\)\s*=\s*)"
                  rb"((?:\d+d\s*)?(?:\d+h\s*)?(?:\d+m\s*)?(?:\d+s)?)")
_M73 = re.compile(rb"^(M73)((?:\s+[PQRSC][-+\d.]+)+)(?=\s|;|$)", re.I)


def format_duration(t_s: float) -> str:
    """PrusaSlicer's style: ``1d 2h 3m 4s`` with leading zero units left out."""
    t = int(round(max(t_s, 0.0)))
    d, rem = divmod(t, 86400)
    h, rem = divmod(rem, 3600)
    m, s = divmod(rem, 60)
    parts = []
    if d:
        parts.append(f"{d}d")
    if d or h:
        parts.append(f"{h}h")
    if d or h or m:
        parts.append(f"{m}m")
    parts.append(f"{s}s")
    return " ".join(parts)


class MetadataUpdater:
    """Rewrites time lines given the elapsed time at each line and the new total."""

    def __init__(self, program, total_s: float):
        self.total_s = float(total_s)

    def update(self, i: int, raw: bytes, t_here_s: float) -> bytes | None:
        if not raw or raw[:1] not in (b";", b"M", b"m"):
            return None
        body, ending = _split_ending(raw)
        total = self.total_s
        m = _TIME.match(body)
        if m:
            return b";TIME:" + str(int(round(total))).encode() + body[m.end():] + ending
        m = _ELAPSED.match(body)
        if m:
            return b";TIME_ELAPSED:" + f"{t_here_s:.6f}".encode() + body[m.end():] + ending
        m = _EST.match(body)
        if m:
            return m.group(1) + format_duration(total).encode() + body[m.end():] + ending
        m = _M73.match(body)
        if m:
            pct = int(round(100.0 * min(max(t_here_s / total, 0.0), 1.0))) if total > 0 else 100
            left_min = int(round(max(total - t_here_s, 0.0) / 60.0))
            words = m.group(2).split()
            new = []
            for w in words:
                L = w[:1].upper()
                if L in (b"P", b"Q"):
                    new.append(L + str(pct).encode())
                elif L in (b"R", b"S"):
                    new.append(L + str(left_min).encode())
                else:
                    new.append(w)
            return m.group(1) + b" " + b" ".join(new) + body[m.end():] + ending
        return None


def _split_ending(raw: bytes) -> tuple[bytes, bytes]:
    if raw.endswith(b"\r\n"):
        return raw[:-2], b"\r\n"
    if raw.endswith(b"\n"):
        return raw[:-1], b"\n"
    return raw, b""


def rescale_times(data: bytes, plan_total_s: float, total_s: float) -> bytes:
    """``data`` (a written file) with its time lines moved from the plan's total to
    ``total_s`` — the firmware model's time of the very file, which the summary reports: the
    total as is, each elapsed time and time left scaled by total_s / plan_total_s (the plan and
    the firmware model part by a fraction of a percent, spread over the print). Lines that are
    not time metadata are untouched; ``data`` is returned as is when the totals agree."""
    if plan_total_s <= 0 or abs(total_s - plan_total_s) < 1e-9:
        return data
    k = total_s / plan_total_s
    up = MetadataUpdater(None, total_s)
    out = []
    for raw in data.splitlines(keepends=True):
        if raw[:1] not in (b";", b"M", b"m"):  # motion and most lines: nothing to look at
            out.append(raw)
            continue
        body, _ = _split_ending(raw)
        t_here = None
        m = _ELAPSED.match(body)
        if m:
            t_here = float(body[len(b";TIME_ELAPSED:"):m.end()]) * k
        else:
            m = _M73.match(body)
            if m:
                words = {w[:1].upper(): w[1:] for w in m.group(2).split()}
                pct = words.get(b"P", words.get(b"Q"))
                t_here = float(pct) / 100.0 * total_s if pct is not None else None
        new = up.update(0, raw, t_here if t_here is not None else 0.0) if (
            _TIME.match(body) or _EST.match(body) or t_here is not None) else None
        out.append(raw if new is None else new)
    return b"".join(out)
