"""Shared fixtures. Reference data is read from ../shared/data (never copied into the repo)."""

from __future__ import annotations

import pathlib

import pytest
from hypothesis import settings

import gcode_feedopt  # noqa: F401  (first: one BLAS thread per process, as the CLI runs)

# The default run draws the same Hypothesis examples every time: a failure reproduces, and a
# pass is not the luck of the draw (a run on 75a4089 drew `F1e-30`, which no run before had).
# `python -m pytest tests/test_fuzz_reader.py --hypothesis-profile=explore` draws new ones.
settings.register_profile("gate", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile("gate")

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
DATA = SHARED / "data"
GCODE_DIR = DATA / "gcode"
MEASURED_DIR = DATA / "measured"
#: benchA: a machine simulated apart from this project (its README and labels.json)
INDEPENDENT_DIR = DATA / "independent"


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


@pytest.fixture(scope="session")
def bench_a():
    """(profile built from benchA's 12 FRFs as ``profile build`` builds it, labels.json)."""
    import json

    from gcode_feedopt.profile import load_profile
    from gcode_feedopt.profile.build import build_from_frfs

    if not INDEPENDENT_DIR.is_dir():
        pytest.skip(f"benchA not found at {INDEPENDENT_DIR}")
    frf = INDEPENDENT_DIR / "frf"
    prof, _ = build_from_frfs(load_profile("ender3pro"),
                              {a: sorted(frf.glob(f"{a}_*.csv")) for a in "xy"}, name="benchA")
    labels = json.loads((INDEPENDENT_DIR / "labels.json").read_text())
    return prof, labels


def bench_a_log(name: str):
    """(cmd (K, 2), measured (K, 2)) of a benchA log, mm."""
    import numpy as np

    a = np.loadtxt(INDEPENDENT_DIR / "logs" / name, delimiter=",", skiprows=1)
    return a[:, 1:3], a[:, 3:5]
