"""The lines the writer adds to tell the firmware the plan's limits, and restore the file's.

Each class follows, line by line, the settings its lines leave in force and writes a line only
where they differ from what the plan needs; the text of the lines is the firmware variant's
(firmware.Firmware: ``stretch_texts``, ``clamp_text``, ``plan_limits_texts``, ...):

- :class:`_AccelState`: the acceleration and junction rule of a slow-down plan's slowed
  stretches (Marlin ``M204 P T``, ``M205 X Y``; Klipper ``SET_VELOCITY_LIMIT ACCEL
  SQUARE_CORNER_VELOCITY``), and the settings in force again after each;
- :class:`_ClampState`: the firmware's acceleration limits clamped to the plan's where the file
  allows more (firmware.AccelClamp; ``M201``, ``SET_VELOCITY_LIMIT ACCEL``), the file's own
  after the last move;
- :class:`_PlanLimits`: the limits the plan is timed with, before the first re-timed move,
  where the printer is configured lower (profile ``firmware.configured_*``), and the
  configured ones after the last move.

``--accel plan`` (firmware.AccelOverride) writes the texts the firmware variant gives it; the
comments it appends to them are here (``_OVERRIDE_WHY``, ``_RESTORE_WHY``).
"""

from __future__ import annotations

from ..firmware import by_flavour

#: the comments on the lines of ``--accel plan``: after a file line lowering an acceleration
#: (or a junction setting), and after the last move
_OVERRIDE_WHY = b" ; gcode-feedopt: the plan's acceleration (--accel plan)"
_OVERRIDE_JUNCTION_WHY = b" ; gcode-feedopt: the plan's junctions (--accel plan)"
_RESTORE_WHY = b" ; gcode-feedopt: the file's own acceleration again"
_RESTORE_JUNCTION_WHY = b" ; gcode-feedopt: the file's own junctions again"


def override_why(text: str, restore: bool = False) -> bytes:
    """The comment on one line of ``--accel plan`` (``text``: its command)."""
    junction = text.startswith("M205") or (
        "SQUARE_CORNER_VELOCITY" in text and "ACCEL=" not in text)
    if restore:
        return _RESTORE_JUNCTION_WHY if junction else _RESTORE_WHY
    return _OVERRIDE_JUNCTION_WHY if junction else _OVERRIDE_WHY


class _AccelState:
    """The acceleration (and junction) settings of slowed stretches, and their restore.

    A slow-down plan (optimize.slowdown) scales a cell's feed cap by r, its acceleration by r²
    and its junction speeds by r: the firmware's own plan at 1/r of the speed. Told the
    cell's acceleration (Marlin: ``M204 P T``; Klipper: ``SET_VELOCITY_LIMIT ACCEL``) and its
    junction rule scaled by r (Marlin's classic jerk ``M205 X Y`` when the file uses it — a
    junction deviation scales with the acceleration by itself; Klipper's
    ``SQUARE_CORNER_VELOCITY``), the firmware runs that plan as planned with one line per
    cell run at the run's peak speed, instead of a staircase of F values it would take at
    full acceleration (slower, and with the acceleration bursts the plan avoided). The values
    in force (the profile's, then the file's) are restored before the next line that is not
    a slowed piece or a comment, and at the end of the file."""

    def __init__(self, settings):
        self.st = settings
        self.fw = by_flavour(settings.flavour)
        self.restores_clamp = self.fw.restore_sets_clamp
        self.active = None  # (accel, r) in force from our lines, or None
        self.lines = 0

    def set(self, key, mi: int, ending: bytes) -> list[bytes]:
        if key == self.active:
            return []
        acc, r = key
        out = [t.encode() + ending for t in self.fw.stretch_texts(acc, r, self.st, mi)]
        self.active = key
        self._mi = mi
        self.lines += len(out)
        return out

    def restore(self, ending: bytes) -> list[bytes]:
        if self.active is None:
            return []
        out = [t.encode() + ending for t in self.fw.stretch_restore_texts(self.st, self._mi)]
        self.active = None
        self.lines += len(out)
        return out


class _ClampState:
    """The firmware's acceleration limits clamped to the plan's (firmware.AccelClamp): a
    line before any move where the limits in force are above the plan's, and the file's own
    values back after the last move. A file line setting them again ends ours (``epoch``)."""

    def __init__(self, clamp):
        self.fw = by_flavour(clamp.flavour)
        # per move, as Python tuples: compared once per motion line
        self.want = [tuple(r) for r in clamp.want_mm_s2.tolist()]
        self.file = [tuple(r) for r in clamp.file_mm_s2.tolist()]
        self.epoch = clamp.epoch.tolist()
        self.ours = None  # (epoch, values) of our last line
        self.lines = 0

    def _line(self, vals, ending: bytes) -> bytes:
        return self.fw.clamp_text(vals).encode() + ending

    def _have(self, mi: int):
        if self.ours is not None and self.ours[0] == self.epoch[mi]:
            return self.ours[1]
        return self.file[mi]

    def before_move(self, mi: int, ending: bytes) -> list[bytes]:
        want = self.want[mi]
        if self._have(mi) == want:
            return []
        self.ours = (self.epoch[mi], want)
        self.lines += 1
        return [self._line(want, ending)]

    def set_to_want(self, mi: int) -> None:
        """Another line of ours (Klipper's ACCEL restore) has set the clamped value."""
        self.ours = (self.epoch[mi], self.want[mi])

    def restore(self, mi: int, ending: bytes) -> list[bytes]:
        """The file's values in force at move ``mi`` (the last), if ours hold."""
        file = self.file[mi]
        if self._have(mi) == file:
            return []
        self.ours = None
        self.lines += 1
        return [self._line(file, ending)]


class _PlanLimits:
    """The acceleration limits the plan is timed with, where the printer as its owner
    configured it runs lower ones (profile ``firmware.configured_*``), and the junction
    setting, where the plan's is above the firmware's (firmware.plan_junction): set before
    the first re-timed move — Marlin ``M201 X Y`` then ``M204 P R T`` and ``M205 J``, Klipper
    ``SET_VELOCITY_LIMIT ACCEL SQUARE_CORNER_VELOCITY`` — with the values the firmware model
    has in force there (the profile's, then the file's own lines), and the configured values
    back after the last move. In between, the file's own settings and our slowed stretches
    start from what the plan assumed."""

    #: the junction setting a file starts with -> the settings' array of it
    _START = {"jd": "jd_mm", "scv": "scv_mm_s"}

    @staticmethod
    def needed(fw, settings) -> bool:
        """Some of the plan's limits may be above the printer's as configured."""
        if fw.configured_accel_mm_s2 is not None or fw.configured_max_accel_mm_s2 is not None:
            return True
        field, key = by_flavour(fw.flavour).start_junction
        vals = getattr(settings, _PlanLimits._START[field])
        return vals is not None and len(vals) > 0 and float(vals.max()) > getattr(fw, key)

    def __init__(self, fw, settings):
        self.fw, self.st = fw, settings
        self.variant = by_flavour(fw.flavour)
        self.done = False
        self.raised = {"max": False, "accel": False, "junction": False}
        self.lines = 0

    def before_first(self, mi: int, ending: bytes) -> list[bytes]:
        if self.done:
            return []
        self.done = True
        why = self._why(ending)
        out = [t.encode() + why
               for t in self.variant.plan_limits_texts(self.fw, self.st, mi, self.raised)]
        self.lines += len(out)
        self.set_lines = tuple(ln.split(b" ;")[0].decode() for ln in out)
        return out

    set_lines: tuple = ()

    @staticmethod
    def _why(ending: bytes) -> bytes:
        return b" ; gcode-feedopt: the limits the plan is timed with" + ending

    def restore(self, ending: bytes) -> list[bytes]:
        ending = b" ; gcode-feedopt: the printer's configured limits again" + ending
        out = [t.encode() + ending for t in self.variant.configured_texts(self.fw, self.raised)]
        self.lines += len(out)
        return out
