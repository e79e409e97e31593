"""Planners: turn a Path into a Schedule (gcode.schedule; path coordinate sampled at Ts)."""
