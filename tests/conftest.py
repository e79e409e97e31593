"""Shared fixtures. Reference data is read from ../shared/data (never copied into the repo)."""

from __future__ import annotations

import pathlib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
DATA = SHARED / "data"
GCODE_DIR = DATA / "gcode"
MEASURED_DIR = DATA / "measured"


def pytest_collection_modifyitems(config, items):
    if not DATA.is_dir():
        skip = pytest.mark.skip(reason=f"reference data not found at {DATA}")
        for item in items:
            if "shared_data" in item.keywords:
                item.add_marker(skip)


@pytest.fixture(scope="session")
def data_dir() -> pathlib.Path:
    if not DATA.is_dir():
        pytest.skip(f"reference data not found at {DATA}")
    return DATA


@pytest.fixture(scope="session")
def gcode_files() -> list[pathlib.Path]:
    files = sorted(GCODE_DIR.glob("*.gcode"))
    if not files:
        pytest.skip(f"no G-code in {GCODE_DIR}")
    return files
