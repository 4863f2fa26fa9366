"""Shared fixtures: the real recorded trajectories in ../shared/data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

DATA_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data"

# The optimizer's compiled model (excite.plan.compiled): a library the cache already holds is
# used, but no test starts the C compiler in the background (minutes of both cores per problem
# shape, in a detached process that would outlive the test); the test of compiling sets its own.
os.environ.setdefault("EXCITE_COMPILE", "0")


@pytest.fixture(scope="session")
def data_dir() -> Path:
    if not DATA_DIR.is_dir():
        pytest.skip(f"real trajectories not found at {DATA_DIR} (CI always has them)")
    return DATA_DIR


def pytest_sessionstart(session) -> None:
    """Load the native module once, before any test: in a source checkout whose sources have no
    build yet, this is where it is compiled (once, into the cache), not inside a test or in the
    worker of a service a test started."""
    from excite.core.native import module

    module()
