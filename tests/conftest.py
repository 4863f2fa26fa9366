"""Shared fixtures: the real recorded trajectories in ../shared/data."""

from __future__ import annotations

from pathlib import Path

import pytest

DATA_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def data_dir() -> Path:
    if not DATA_DIR.is_dir():
        pytest.skip(f"real trajectories not found at {DATA_DIR} (CI always has them)")
    return DATA_DIR
