"""Fixtures of the optimizer tests (synthetic helpers live in synthetic.py)."""

from __future__ import annotations

import pytest

from .synthetic import second_order_impulse


@pytest.fixture
def mode40():
    """A 40 Hz, ζ = 0.05 unit-gain mode at Ts = 2 ms (an Ender-3-like first mode)."""
    return second_order_impulse(40.0, 0.05, 0.002)
