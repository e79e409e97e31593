"""Machine profiles: schema (schema.py) and files (io.py)."""

from .io import builtin_names, load_profile, parse_profile, save_profile
from .schema import AxisModel, Firmware, FRFSet, Limits, MachineProfile, Mode, Prior, TwinSettings

__all__ = ["load_profile", "save_profile", "parse_profile", "builtin_names", "MachineProfile",
           "Limits", "Firmware", "FRFSet", "Mode", "Prior", "AxisModel", "TwinSettings"]
