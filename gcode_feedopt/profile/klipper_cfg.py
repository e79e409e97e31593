"""The input shaper a Klipper printer runs, read from its printer.cfg ([input_shaper]).

Klipper's keys: ``shaper_freq_x`` / ``shaper_freq_y`` (0: off), ``shaper_type`` (default
``mzv``) or ``shaper_type_x`` / ``shaper_type_y``, ``damping_ratio_x`` / ``damping_ratio_y``
(default 0.1). ``SAVE_CONFIG`` writes its results in a block at the file's end whose lines start
with ``#*#``; that block overrides the sections above it, as Klipper reads it. Klipper centres
its pulses (firmware.shaper). Types we have no closed form for (2hump_ei, 3hump_ei, smooth
shapers) are refused with the way round: state them as ``custom`` pulses in the profile.
"""

from __future__ import annotations

import re

from ..errors import ProfileError
from ..firmware.shaper import TYPES, Shaper
from ..inputs import read_text

_SECTION = re.compile(r"^\[([^\]]+)\]\s*$")
_KEY = re.compile(r"^([A-Za-z0-9_]+)\s*[:=]\s*(.*?)\s*$")


def _sections(text: str) -> dict:
    """{section: {key: (value, line number)}} of a Klipper config, the SAVE_CONFIG block's
    (``#*#`` lines) read after the rest so that it overrides it."""
    plain, saved = [], []
    for no, line in enumerate(text.splitlines(), 1):
        if line.startswith("#*#"):
            saved.append((no, line[3:].strip()))
        else:
            plain.append((no, line.split("#", 1)[0].split(";", 1)[0].rstrip()))
    out: dict = {}
    for block in (plain, saved):
        cur = None
        for no, line in block:
            if not line.strip():
                continue
            m = _SECTION.match(line.strip())
            if m:
                cur = out.setdefault(m.group(1).strip().lower(), {})
                continue
            m = _KEY.match(line.strip())
            if m and cur is not None and not line[:1].isspace():
                cur[m.group(1).lower()] = (m.group(2), no)
    return out


def read_input_shaper(path) -> dict:
    """{"x"|"y": Shaper} of the [input_shaper] section of a Klipper printer.cfg at ``path``
    (axes whose frequency is 0 or absent are not shaped); one-line ProfileError otherwise."""
    name = str(path)
    text = read_text(path, "a Klipper printer.cfg", ProfileError)
    sec = _sections(text).get("input_shaper")
    if sec is None:
        raise ProfileError(f"{name}: no [input_shaper] section (in an [include]d file? give that "
                           "file); a printer without one needs no --klipper-config")

    def num(key, default):
        v, no = sec.get(key, (None, 0))
        if v is None:
            return default
        try:
            return float(v)
        except ValueError:
            raise ProfileError(f"{name}:{no}: {key} = {v!r} is not a number") from None

    out = {}
    for ax in "xy":
        f = num(f"shaper_freq_{ax}", 0.0)
        if f <= 0:
            continue
        kind, no = sec.get(f"shaper_type_{ax}", sec.get("shaper_type", ("mzv", 0)))
        kind = kind.strip().lower()
        if kind not in TYPES or kind == "custom":
            raise ProfileError(f"{name}:{no}: shaper type {kind!r} has no closed form here (we "
                               f"have {', '.join(t for t in TYPES if t != 'custom')}); state its "
                               "pulses in the profile as firmware.input_shaper."
                               f"{ax}: {{type: custom, amplitudes: [...], times_s: [...]}}")
        z = num(f"damping_ratio_{ax}", 0.1)
        if not (0 <= z < 1):
            raise ProfileError(f"{name}: damping_ratio_{ax} = {z:g} must lie in [0, 1)")
        out[ax] = Shaper(kind, f, z, centred=True)
    if not out:
        raise ProfileError(f"{name}: [input_shaper] shapes no axis (shaper_freq_x / _y absent or "
                           "0); a printer without a shaper needs no --klipper-config")
    return out
