"""A command imports only what it uses (the cold path a person waits on): `excite --help` loads
neither scipy nor numba, `excite score` neither the optimizer, the plots, the service nor the
path planner's filters."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

PROBE = """
import contextlib, io, json, sys
from excite.cli import main
with contextlib.redirect_stdout(io.StringIO()):
    rc = main(sys.argv[2:])
print(json.dumps([rc, sorted(m for m in sys.modules if m.split(".")[0] in {names})
                  + sorted(m for m in sys.modules if m in {exact})]))
"""


def _loaded(args: list[str], top: set[str], exact: set[str]) -> tuple[int, list[str]]:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    code = PROBE.format(names=repr(top), exact=repr(exact))
    r = subprocess.run([sys.executable, "-c", code, "-", *args], cwd=REPO, env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    rc, mods = json.loads(r.stdout.strip().splitlines()[-1])
    return rc, mods


def test_help_imports_neither_scipy_nor_numba():
    rc, mods = _loaded(["--help"], {"scipy", "numba", "numpy", "matplotlib", "fastapi", "casadi",
                                    "rosbags"}, set())
    assert rc == 0 and mods == [], mods


def test_score_imports_only_what_scoring_uses():
    rc, mods = _loaded(["score", "trajectories/figure_eight_control.csv"],
                       {"matplotlib", "fastapi", "casadi", "uvicorn"},
                       {"scipy.ndimage", "excite.optimize", "excite.plots", "excite.rig_import"})
    assert rc == 0 and mods == [], mods
