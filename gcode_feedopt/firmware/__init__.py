"""Printer firmwares: each one's rules behind one small interface, and the per-file replay of
the settings a file sets.

The printer's firmware re-plans every move with its own limits, so the commanded trajectory is
the firmware's; a plan the firmware would run slower is not the plan. One variant per file,
chosen by the profile's ``firmware.flavour`` (:func:`firmware_for`):

- base.py: the interface (:class:`Firmware`: how a line changes the limits, per-move caps,
  junction rule and look-ahead, the text of the commands that set and restore limits) and
  the :class:`Limits` in force;
- marlin.py: Marlin 2; klipper.py: Klipper (docs/firmware.md);
- replay.py: the file's settings replayed once (:class:`Replay`) and what the planner
  (:class:`MoveLimits`) and the writer (:class:`AccelSettings`, :class:`AccelClamp`) read;
- variants.py: the one factory, :func:`firmware_for` (:func:`by_flavour`);
- override.py: ``--accel plan`` (:class:`AccelOverride`) and the configured printer;
- blocks.py: the firmware's planner blocks (vm.firmware times and samples them);
- shaper.py: the input shaper between planner and motors (what the machine receives).
"""

from __future__ import annotations

from .base import Firmware, Limits, plan_junction
from .blocks import Blocks, build_blocks
from .klipper import Klipper
from .marlin import Marlin
from .override import (ACCELS, AccelOverride, accel_override, as_configured,
                       firmware_junctions, override_restore_texts, plan_accels,
                       raises_configured)
from .replay import (AccelClamp, AccelSettings, MoveLimits, Replay, accel_clamp, accel_settings,
                     move_limits)
from .variants import LIMIT_COMMANDS, by_flavour, firmware_for

__all__ = ["ACCELS", "AccelClamp", "AccelOverride", "AccelSettings", "Blocks", "Firmware",
           "Klipper", "LIMIT_COMMANDS", "Limits", "Marlin", "MoveLimits", "Replay", "accel_clamp",
           "accel_override", "accel_settings", "as_configured", "build_blocks", "by_flavour",
           "firmware_for", "firmware_junctions", "move_limits", "override_restore_texts",
           "plan_accels", "plan_junction", "raises_configured"]
