"""The variants by flavour, and the one factory (re-exported by the package)."""

from __future__ import annotations

from .base import Firmware
from .klipper import Klipper
from .marlin import Marlin

_VARIANTS = {v.flavour: v() for v in (Marlin, Klipper)}
#: every command a variant's added lines may start with (gcode.verify)
LIMIT_COMMANDS = tuple(c for v in _VARIANTS.values() for c in v.limit_commands)


def by_flavour(flavour: str) -> Firmware:
    """The variant of a profile's ``firmware.flavour`` (``marlin``, ``klipper``)."""
    try:
        return _VARIANTS[flavour]
    except KeyError:
        raise ValueError(f"unknown firmware flavour {flavour!r}; use one of "
                         f"{', '.join(_VARIANTS)}") from None


def firmware_for(profile) -> Firmware:
    """The variant whose rules the profile's printer runs (``profile.firmware.flavour``)."""
    return by_flavour(profile.firmware.flavour)
