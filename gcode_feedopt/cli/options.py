"""Options shared by the sub-commands: bounded numbers (one rule, one message shape) and the
profile file an output must not replace."""

from __future__ import annotations

import pathlib


def profile_files(machine: str) -> list[pathlib.Path]:
    """The profile file ``--machine`` names, when it is a file (an input no output may
    replace)."""
    p = pathlib.Path(machine)
    return [p] if p.suffix.lower() in (".yaml", ".yml") and p.is_file() else []
