"""Planners: turn a Path into a Schedule (path coordinate sampled at Ts)."""

from .schedule import Schedule

__all__ = ["Schedule"]
