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
    """Compile the evaluator's kernels once, before any test: numba caches them next to the
    sources, so the services the tests start (whose workers warm up within a time limit) load
    them instead of each compiling them on a fresh clone."""
    import numpy as np

    from excite.score.evaluate import evaluate
    from excite.rig.config import load_rig
    from excite.motion.vehicle import ControlProfile, drive

    rig = load_rig("robotaxi")
    t = np.linspace(0.0, 20.0, 21)
    evaluate(drive(ControlProfile(t, 5 + 2 * np.sin(t), 0.1 * np.sin(t / 2)), rig.suspension), rig)
