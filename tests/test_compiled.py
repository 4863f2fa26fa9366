"""The kernels built ahead of time (what a one-shot command loads, excite.compiled) against numba's
JIT kernels: the same reports; a wrong argument raises instead of being read as another type; a
module built from other sources is never used; when no module can be had, the JIT is used and
the command says so once."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from excite import compiled, kernels
from excite.evaluate import evaluate
from excite.rig import load_rig
from excite.routes import read_route

REPO = Path(__file__).resolve().parents[1]
ROUTES = ["trajectories/figure_eight.tum", "trajectories/slalom_control.csv", "trajectories/stop_and_go.tum"]


def _env(**extra: str) -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]), **extra)


@pytest.fixture(scope="module")
def built() -> Path:
    """The ahead-of-time module of this checkout, in the user's cache (built once per change of
    the kernels, as the first one-shot command would; shared with the command-line tests)."""
    r = subprocess.run([sys.executable, "-m", "excite.compiled"], cwd=REPO, env=_env(), capture_output=True,
                       text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-3000:]
    return compiled.cache_dir()


REPORTS = """
import json, sys
from excite import compiled
compiled.ahead_of_time()
from excite.evaluate import evaluate
from excite.rig import load_rig
from excite.routes import read_route
rig = load_rig("robotaxi")
out = []
for route in sys.argv[1:]:
    rep = evaluate(read_route(route, suspension=rig.suspension), rig)
    out.append({"sigma": [p.sigma for p in rep.parameters], "score": rep.score,
                "information": rep.information.tolist()})
print(json.dumps({"mode": compiled.mode(), "numba": "numba" in sys.modules, "reports": out}))
"""


def test_ahead_of_time_kernels_give_the_jit_reports(built):
    r = subprocess.run([sys.executable, "-c", REPORTS, *ROUTES], cwd=REPO, env=_env(), capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-3000:]
    child = json.loads(r.stdout.strip().splitlines()[-1])
    assert child["mode"] == "aot" and child["numba"] is False
    assert compiled.mode() == "jit"  # this process: numba's dispatchers
    rig = load_rig("robotaxi")
    for route, aot in zip(ROUTES, child["reports"]):
        rep = evaluate(read_route(REPO / route, suspension=rig.suspension), rig)
        jit = [p.sigma for p in rep.parameters]
        assert len(jit) == len(aot["sigma"]) > 20
        for a, j in zip(aot["sigma"], jit):
            assert (a is None) == (j is None)
            if j is not None:
                assert abs(a - j) <= 1e-12 * abs(j), (route, a, j)
        Lam = np.array(aot["information"])
        assert np.abs(Lam - rep.information).max() <= 1e-12 * np.abs(rep.information).max()
        assert abs(aot["score"] - rep.score) <= 1e-12 * abs(rep.score)


def _aot(built: Path):
    module, table = compiled.load(built, compiled.key())
    return compiled._AheadOfTime(module, table)


def test_a_wrong_argument_raises_instead_of_being_read_as_another_type(built):
    aot = _aot(built)
    segments = aot.njit(cache=True, nogil=True)(kernels.segments.py_func)
    eliminate = aot.njit(cache=True, nogil=True)(kernels.eliminate.py_func)
    preintegration = aot.njit(cache=True, nogil=True)(kernels.preintegration.py_func)
    assert isinstance(segments, compiled.Kernel)
    breaks = np.array([0.0, 1.0, 2.5, 4.0])
    t = np.array([3.0, -1.0, 0.5, 1.0, 9.0, 2.5])
    expected = np.clip(np.searchsorted(breaks, t, side="right") - 1, 0, breaks.size - 2)
    assert np.array_equal(segments(breaks, t), expected)
    wrong = {"float32": (breaks.astype(np.float32), t), "int64": (breaks, t.astype(np.int64)),
             "2-d": (breaks[None], t), "strided": (breaks, np.repeat(t, 2)[::2]), "a list": (list(breaks), t),
             "one argument too few": (breaks,), "one too many": (breaks, t, t)}
    for name, args in wrong.items():
        with pytest.raises(TypeError, match="excite.kernels.segments: no compiled signature takes"):
            segments(*args)
    sd, q = 9, 4
    band = np.zeros((2, 3, sd, sd))
    band[0] = np.eye(sd)
    Hxe, Hee = np.zeros((3, sd, q)), np.eye(q)
    read_only = band.copy()
    read_only.flags.writeable = False
    with pytest.raises(TypeError, match="read-only"):  # eliminate writes into band
        eliminate(read_only, Hxe, Hee, 0, 3)
    with pytest.raises(TypeError):  # Fortran order
        eliminate(np.asfortranarray(band), Hxe, Hee, 0, 3)
    with pytest.raises(TypeError):  # a float where the kernel takes an integer
        eliminate(band, Hxe, Hee, 0.0, 3)
    assert eliminate(band, Hxe, Hee, np.int64(0), 3) == -1  # numpy integers are integers
    R = np.tile(np.eye(3), (5, 1, 1))
    f = np.zeros((5, 3))
    with pytest.raises(TypeError):  # a bool is not a sample count
        preintegration(R, f, True, 2, 0.01, 1e-3, 1e-2)
    out = preintegration(R, f, 2, 2, 1, 1e-3, 1e-2)  # an int where the kernel takes a float
    assert np.allclose(out[0], np.eye(3))


def test_a_module_built_from_other_sources_is_not_used(built, tmp_path):
    here = compiled.key()
    assert compiled.load(built, here) is not None
    copy = tmp_path / "excite"
    for path in compiled.sources():
        dest = copy / path.relative_to(REPO / "excite")
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, dest)
    assert compiled.key(copy) == here  # the same sources, wherever they are
    changes = {  # a kernel's body; a constant a kernel reads from another module; the builder
        "kernels.py": ("out[i] = k\n", "out[i] = k + 0\n"),
        "trajectory.py": ("GRAVITY = np.array([0.0, 0.0, -9.80665])", "GRAVITY = np.array([0.0, 0.0, -9.81])"),
        "compiled.py": ("_KEEP = 4", "_KEEP = 5"),
    }
    for name, (old, new) in changes.items():
        text = (copy / name).read_text()
        assert old in text, name
        (copy / name).write_text(text.replace(old, new))
        stale = compiled.key(copy)
        assert stale != here, name
        assert compiled.load(built, stale) is None, name  # not found: the next command builds it
        (copy / name).write_text(text)
    assert compiled.key(copy) == here


def test_every_module_with_kernels_is_listed():
    """A module of numba kernels left out of MODULES would be neither built nor hashed."""
    with_kernels = set()
    for path in (REPO / "excite").rglob("*.py"):
        if re.search(r"^@nb\.njit", path.read_text(), re.M):
            with_kernels.add(".".join(path.relative_to(REPO).with_suffix("").parts))
    assert with_kernels == set(compiled.MODULES)


def _score(env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "excite.cli", "score", "trajectories/figure_eight.tum", "--json"],
                          cwd=REPO, env=_env(**env), capture_output=True, text=True, timeout=600)


def test_without_a_module_the_command_uses_the_jit_and_says_so_once(tmp_path):
    not_a_directory = tmp_path / "file"
    not_a_directory.write_text("")
    r = _score({"XDG_CACHE_HOME": str(not_a_directory)})
    assert r.returncode == 0, r.stderr[-3000:]
    assert json.loads(r.stdout)["route"] == "figure_eight"
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("excite: using numba's JIT: the ahead-of-time kernels cannot be stored in")
    # a build that failed is not retried on every command (until its record is deleted)
    cache = tmp_path / "cache"
    failed = cache / "excite" / "kernels" / f"{compiled._PREFIX}{compiled.key()}.failed"
    failed.parent.mkdir(parents=True)
    failed.write_text("no C compiler")
    r = _score({"XDG_CACHE_HOME": str(cache)})
    assert r.returncode == 0 and json.loads(r.stdout)["route"] == "figure_eight"
    assert r.stderr.splitlines() == [f"excite: using numba's JIT: building the kernels ahead of time failed "
                                     f"before (see {failed}; delete it to retry)"]
