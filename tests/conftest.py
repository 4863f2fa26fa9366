"""Shared fixtures: the real recorded trajectories in ../shared/data."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

DATA_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data"

# The optimizer's compiled model (excite.plan.compiled): a library the cache already holds is
# used, but no test starts the C compiler by accident (minutes of both cores per problem shape);
# the tests of compiling set their own.
os.environ.setdefault("EXCITE_COMPILE", "0")

# The commands print their tables as wide as COLUMNS says, or excite.cli.app.PIPE_WIDTH when
# piped. pytest imports GNU readline, which exports its guess of a terminal (COLUMNS=80, LINES=24
# without one) into the environment child processes inherit — pytest-xdist's workers, and
# commands a test starts without an environment of its own — though not into os.environ: a table
# would be 80 columns wide in a worker and PIPE_WIDTH in one process. Tests run without either,
# whoever started them; a test that wants a width sets COLUMNS itself.
for _name in ("COLUMNS", "LINES"):
    os.environ.pop(_name, None)
    os.unsetenv(_name)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config) -> int:
    """``-n auto``: a worker per CPU this process may run on (xdist's own count is the physical
    cores, one on a two-vCPU machine whose vCPUs are one core's two threads)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


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
