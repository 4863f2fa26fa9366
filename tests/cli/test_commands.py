"""A command imports only what it uses (the cold path a person waits on): `excite --help` loads
neither numpy nor scipy, `excite score` of a file neither CasADi, the optimizer, the plots, the
service, the path planner's filters, the bag readers nor the kernels' generator; and the `excite`
process ends with the command's exit code and all of its output."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from helpers import REPO


PROBE = """
import contextlib, io, json, sys
from excite.cli.app import main
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


def test_help_imports_neither_numpy_nor_scipy():
    rc, mods = _loaded(["--help"], {"scipy", "numpy", "matplotlib", "fastapi", "casadi", "rosbags"}, set())
    assert rc == 0 and mods == [], mods


@pytest.mark.parametrize("route", ["figure_eight_control.csv", "figure_eight.tum"])
def test_score_imports_only_what_scoring_uses(route):
    rc, mods = _loaded(["score", f"trajectories/{route}"],
                       {"matplotlib", "fastapi", "casadi", "uvicorn", "rosbags"},
                       {"scipy.ndimage", "scipy.integrate", "excite.plan", "excite.score.plots",
                        "excite.rig.importers", "excite.io.bags", "excite.factors.generate"})
    assert rc == 0 and mods == [], mods


def test_the_excite_process_exits_with_the_commands_code_and_all_its_output():
    """``python -m excite.cli`` runs what the ``excite`` script runs (:func:`excite.cli.app.run`,
    which leaves the interpreter with the command's exit code after freezing the collector)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))
    cmd = [sys.executable, "-m", "excite.cli", "score"]
    ok = subprocess.run([*cmd, "trajectories/figure_eight.tum", "--json"], cwd=REPO, env=env,
                        capture_output=True, text=True, timeout=300)
    assert ok.returncode == 0, ok.stderr[-2000:]
    report = json.loads(ok.stdout)  # the whole report reached the pipe
    assert report["route"] == "figure_eight" and len(report["parameters"]) > 0
    bad = subprocess.run([*cmd, "no_such_route.tum"], cwd=REPO, env=env, capture_output=True,
                         text=True, timeout=300)
    assert bad.returncode == 1 and bad.stdout == ""
    assert bad.stderr.splitlines() == ["excite: error: no_such_route.tum: No such file or directory"]
