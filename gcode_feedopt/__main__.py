"""``python -m gcode_feedopt`` = the ``gcode-feedopt`` command."""

from .cli import main

main()
