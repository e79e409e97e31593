#!/bin/sh
# Re-make the bundled PrusaSlicer sample: STL from the script, sliced headless by Debian's
# prusa-slicer (2.5) with sample_gcode/ender3.ini.
set -e
cd "$(dirname "$0")"
python3 make_part_stl.py part.stl
prusa-slicer --export-gcode --load ender3.ini --center 117.5,117.5 -o part_prusaslicer.gcode part.stl
