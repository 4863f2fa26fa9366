"""Every benchmark script (``benchmarks/bench_*.py``) can be run: its module loads (its imports — of the
library, the test helpers it starts servers with, the results writer — resolve), in one
subprocess, without running its ``main``."""

from __future__ import annotations

import subprocess
import sys

import pytest

from helpers import REPO

LOAD = """
import importlib.util, sys, traceback
failed = []
for path in sys.argv[1:]:
    name = "bench_module_" + path.rsplit("/", 1)[-1][:-3]
    spec = importlib.util.spec_from_file_location(name, path)
    try:
        spec.loader.exec_module(importlib.util.module_from_spec(spec))
    except BaseException as exc:
        failed.append(f"{path}: {type(exc).__name__}: {exc}")
print("\\n".join(failed))
sys.exit(1 if failed else 0)
"""


@pytest.mark.slow
def test_every_benchmark_script_loads():
    scripts = sorted(str(p) for p in (REPO / "benchmarks").glob("bench_*.py"))
    assert len(scripts) > 10
    r = subprocess.run([sys.executable, "-c", LOAD, *scripts], cwd=REPO / "benchmarks", capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr[-2000:]
