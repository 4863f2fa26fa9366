"""Every example in README.md runs as written.

Each ```bash block line (continuations joined, `&&` chains split) and each ```python block is run
in a scratch folder that mirrors the repository's top level (so outputs such as junit.xml land
there, not in the repository) next to a `shared` link (so `../shared/data` resolves as in a
checkout). Installing (`pip install`) and the test command itself are skipped; a trailing
`# exit N` says the command must exit with N (the gate examples that fail on purpose).
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from helpers import REPO

ROOT = REPO
README = ROOT / "README.md"
SHARED = ROOT.parent / "shared"
SKIP = ("python3 -m pip", "pip ", "python -m pip", "python3 -m pytest", "python -m pytest", "pytest",
        "docker ", "excite serve")
TIMEOUT_S = 600


def _blocks(text: str) -> list[tuple[str, str]]:
    return re.findall(r"^```(bash|python)[^\n]*\n(.*?)^```", text, flags=re.M | re.S)


def commands(text: str) -> list[tuple[str, int]]:
    """(shell command, expected exit code) of every bash example, in order."""
    out = []
    for lang, body in _blocks(text):
        if lang != "bash":
            continue
        for line in body.replace("\\\n", " ").splitlines():
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            m = re.search(r"\s#\s*exit\s+(\d+)\s*$", line)
            code = int(m.group(1)) if m else 0
            line = re.sub(r"\s#.*$", "", line).strip()
            for part in (p.strip() for p in line.split("&&")):
                if part and not part.startswith(SKIP):
                    out.append((part, code))
    return out


def python_blocks(text: str) -> list[str]:
    return [body for lang, body in _blocks(text) if lang == "python"]


TEXT = README.read_text()
COMMANDS = commands(TEXT)
PYTHON = python_blocks(TEXT)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """A scratch checkout: links to the repository's top-level entries, and ../shared."""
    base = tmp_path_factory.mktemp("readme")
    work = base / "repo"
    work.mkdir()
    for entry in ROOT.iterdir():
        if entry.name not in (".git",):
            (work / entry.name).symlink_to(entry)
    if SHARED.is_dir():
        (base / "shared").symlink_to(SHARED)
    return work


def run(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, COLUMNS="100")
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)


def test_the_readme_has_examples():
    assert COMMANDS[0] == ("excite score trajectories/figure_eight_control.csv", 0)
    assert any(c.startswith("excite batch trajectories/manifest.yaml") for c, _ in COMMANDS)
    assert any(code == 1 for _, code in COMMANDS)  # a gate example that fails on purpose
    assert PYTHON


@pytest.mark.slow
@pytest.mark.parametrize("command, code", COMMANDS, ids=[c[:70] for c, _ in COMMANDS])
def test_command_runs_as_written(command: str, code: int, workdir: Path):
    if "../shared/data" in command and not SHARED.joinpath("data").is_dir():
        pytest.skip("needs ../shared/data (CI has it)")
    res = run(["bash", "-c", command], workdir)
    assert res.returncode == code, f"{command}\nstdout:\n{res.stdout[-3000:]}\nstderr:\n{res.stderr[-3000:]}"
    assert "Traceback" not in res.stderr
    if command.startswith("excite score") and "--json" not in command:
        assert "score λ_min(SΛS) =" in res.stdout
    for arg in shlex.split(command):
        if arg.endswith(".png") and "--plot" in command:
            assert (workdir / arg).read_bytes()[:4] == b"\x89PNG"
        if arg.endswith(".xml") and "--junit" in command:
            assert (workdir / arg).read_text().startswith("<?xml")


@pytest.mark.slow
@pytest.mark.parametrize("code", PYTHON, ids=[f"python-{i}" for i in range(len(PYTHON))])
def test_python_example_runs_as_written(code: str, workdir: Path):
    res = run([sys.executable, "-c", code], workdir)
    assert res.returncode == 0, res.stderr[-3000:]


def test_files_the_examples_use_are_in_git():
    """A fresh clone has every repository file the examples name (untracked files would pass here
    and fail there)."""
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    tracked = set(subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                                 check=True).stdout.splitlines())
    def in_repo(arg: str) -> bool:
        return (ROOT / arg).is_file() and ROOT.resolve() in (ROOT / arg).resolve().parents

    named = set()
    for command, _ in COMMANDS:
        named |= {a for a in shlex.split(command) if in_repo(a)}
    for body in PYTHON:
        named |= {a for a in re.findall(r'"([^"]+)"', body) if in_repo(a)}
    named |= set(re.findall(r"\]\((docs/[^)]+)\)", TEXT))
    assert named, "no repository files named by the examples?"
    assert named <= tracked, f"not committed: {sorted(named - tracked)}"
    for image in re.findall(r"\]\((docs/[^)]+\.png)\)", TEXT):
        assert (ROOT / image).stat().st_size < 200_000, f"{image} is over 200 KB"
