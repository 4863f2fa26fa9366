"""Every example in README.md and the documentation site runs as written.

A *command block* is a fenced ```bash or ```python block, or a ```text (or untagged) block whose
first line is a shell prompt (``$ ``) or a command (``excite …``, ``python3 …``), unless it is
the output excerpt of the block before it. Every command block is run, unless an HTML comment right before it says
why it cannot be (``<!-- not run: it builds a container image -->``); a prompt transcript must
say so too, since it is not run as it stands.

Each ```bash line (continuations joined, ``&&`` chains split) and each ```python block runs in a
scratch folder that mirrors the repository's top level (so outputs such as junit.xml land there,
not in the repository) next to a ``shared`` link (so ``../shared/data`` resolves as in a
checkout). A trailing ``# exit N`` says the command must exit with N (the gate examples that
fail on purpose). Two kinds of line are not run, each for its stated reason: installing with pip
(the test runs inside that installation) and the test command itself (it is what runs this).
A command that appears word for word in several blocks (the figure-eight scored on several pages)
is run once, in the same scratch folder, and each block checks its excerpt against that run.
``excite serve`` is started on a free loopback port (``--port`` added or replaced: the documented
port may be taken), must become ready, and is stopped.

A ```text block right after a block is its output excerpt, checked loosely against what the
block printed: most of its lines (¾) must appear, their words in order, in the output (tables'
box characters and spacing ignored, ``…``, ``...`` and ``(excerpt)`` skipped). A number matches a
number with the same unit within a factor of 2, and a duration (a number before ``s``, ``ms`` or
``min``) any duration: what a run under a time budget finds (iterations, its plan's score) and how
long a command takes move with the machine's speed; the order of magnitude and the words do not.
"""

from __future__ import annotations

import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import pytest

from helpers import REPO

SHARED = REPO.parent / "shared"
PAGES = [REPO / "README.md"] + sorted((REPO / "docs").rglob("*.md"))
SKIP = {"python3 -m pip": "installs (the test runs inside that installation)",
        "python -m pip": "installs (the test runs inside that installation)",
        "python3 -m pytest": "the test command (it is what runs this test)",
        "python -m pytest": "the test command (it is what runs this test)"}
TIMEOUT_S = 600
BOX = re.compile(r"[─━│┃┌┐└┘┏┓┗┛├┤┬┴┼┡┩╇╈┣┫╋╸╺═║╔╗╚╝▁▂▃▄▅▆▇█]")


@dataclass
class Block:
    page: Path
    line: int
    lang: str
    body: str
    not_run: str | None
    excerpt: str | None
    is_excerpt: bool = False

    @property
    def id(self) -> str:
        return f"{self.page.relative_to(REPO)}:{self.line}"

    @property
    def is_command(self) -> bool:
        first = self.body.lstrip().splitlines()[0] if self.body.strip() else ""
        looks_run = bool(re.match(r"(excite|python3?|pip|curl|docker|podman|dask|[A-Z][A-Z_]*=\S*) ", first))
        return self.lang in ("bash", "sh", "shell", "console", "python") or first.startswith("$ ") or \
            (self.lang in ("", "text") and looks_run and not self.is_excerpt)


FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```[ \t]*$", re.M | re.S)
NOT_RUN = re.compile(r"<!--\s*not run:\s*(.*?)\s*-->\s*$", re.S)


def blocks(page: Path) -> list[Block]:
    text = page.read_text()
    found = list(FENCE.finditer(text))
    out = []
    for i, m in enumerate(found):
        before = text[found[i - 1].end() if i else 0:m.start()]
        reason = NOT_RUN.search(before)
        excerpt = None
        if i + 1 < len(found) and found[i + 1].group(1) == "text":
            between = text[m.end():found[i + 1].start()]
            if not between.strip():
                excerpt = found[i + 1].group(2)
        out.append(Block(page, text.count("\n", 0, m.start()) + 1, m.group(1), m.group(2),
                         reason.group(1) if reason else None, excerpt,
                         is_excerpt=bool(out) and out[-1].excerpt is not None and m.group(1) == "text"))
    return out


ALL = [b for page in PAGES for b in blocks(page)]
RUN = [b for b in ALL if b.is_command and b.not_run is None and b.lang in ("bash", "python")]


def commands(body: str) -> list[tuple[str, int]]:
    """(shell command, expected exit code) of every line of a bash block, in order."""
    out = []
    for line in body.replace("\\\n", " ").splitlines():
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        m = re.search(r"\s#\s*exit\s+(\d+)\s*$", line)
        code = int(m.group(1)) if m else 0
        line = re.sub(r"\s#.*$", "", line).strip()
        for part in (p.strip() for p in line.split("&&")):
            if part and not part.startswith(tuple(SKIP)):
                out.append((part, code))
    return out


def _words(text: str) -> list[str]:
    return BOX.sub(" ", text).replace("…", " ").split()


NUMBER = re.compile(r"^([-+]?(?:\d+\.?\d*|\.\d+)(?:e[-+]?\d+)?)(\D*)$", re.I)


def _same(published: str, printed: str, duration: bool = False) -> bool:
    """Whether a published word stands for a printed one: equal, or numbers with the same unit
    within a factor of 2 (any two durations: how long a command took is the machine's)."""
    if published == printed:
        return True
    a, b = NUMBER.match(published), NUMBER.match(printed)
    if not (a and b) or a.group(2) != b.group(2):
        return False
    x, y = float(a.group(1)), float(b.group(1))
    return x == y or (x * y > 0 and (duration or 0.5 <= x / y <= 2.0))


def excerpt_lines_found(excerpt: str, output: str) -> tuple[int, list[str]]:
    """How many lines of ``excerpt`` appear in ``output`` (their words in order, within a window),
    and those that do not."""
    words = _words(output)
    lines = [ln for ln in excerpt.splitlines()
             if _words(ln) and ln.strip() not in ("...", "…") and not ln.lstrip().startswith("$ ")]
    missing = []
    for ln in lines:
        want = [w for w in _words(ln.replace("(excerpt)", "")) if w not in ("...",)]
        ok = False
        for start in (k for k, w in enumerate(words) if _same(want[0], w)):
            k, end, hit = start, start + 4 * len(want) + 8, True
            for i, w in enumerate(want[1:], 1):
                duration = i + 1 < len(want) and want[i + 1] in ("s", "ms", "min")
                k = next((j for j in range(k + 1, min(end, len(words) - 1) + 1) if _same(w, words[j], duration)), None)
                if k is None:
                    hit = False
                    break
            if hit:
                ok = True
                break
        if not ok:
            missing.append(ln)
    return len(lines), missing


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """A scratch checkout: links to the repository's top-level entries, and ../shared."""
    base = tmp_path_factory.mktemp("examples")
    work = base / "repo"
    work.mkdir()
    for entry in REPO.iterdir():
        if entry.name not in (".git", "out", "site"):
            (work / entry.name).symlink_to(entry)
    if SHARED.is_dir():
        (base / "shared").symlink_to(SHARED)
    return work


_RUNS: dict[str, subprocess.CompletedProcess] = {}  # command → its run in the scratch folder


def _run(command: str, cwd: Path) -> subprocess.CompletedProcess:
    if command not in _RUNS:
        _RUNS[command] = subprocess.run(["bash", "-c", command], cwd=cwd, env=_env(), capture_output=True, text=True,
                                        timeout=TIMEOUT_S)
    return _RUNS[command]


def _env() -> dict[str, str]:
    # COLUMNS: tables as wide as a terminal; the optimizer never starts the C compiler here
    return dict(os.environ, COLUMNS="200", EXCITE_COMPILE="0", EXCITE_RESIDENT="0")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _serve(command: str, cwd: Path) -> str:
    port = _free_port()
    args = shlex.split(command)
    if "--port" in args:
        args[args.index("--port") + 1] = str(port)
    else:
        args += ["--port", str(port)]
    proc = subprocess.Popen(args, cwd=cwd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            assert proc.poll() is None, f"{command} exited with {proc.returncode}:\n{proc.stdout.read()}"
            try:
                if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=2).status_code == 200:
                    return f"served on port {port}"
            except httpx.HTTPError:
                pass
            time.sleep(0.3)
        raise AssertionError(f"{command}: not ready within 120 s")
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()


def test_the_docs_have_examples():
    readme = [b for b in ALL if b.page.name == "README.md" and b.lang == "bash"]
    first = commands(readme[0].body)
    assert first[0] == ("excite score trajectories/figure_eight_control.csv", 0)
    assert readme[0].body.splitlines() == [
        'python3 -m pip install -e ".[test]" && excite score trajectories/figure_eight_control.csv',
        "python3 -m pytest -q -n auto"]
    runs = [c for b in RUN if b.lang == "bash" for c, _ in commands(b.body)]
    for cmd in ("excite score", "excite optimize", "excite validate", "excite live", "excite serve", "excite batch",
                "excite mine"):
        assert any(c.startswith(cmd) for c in runs), f"no runnable example of {cmd}"
    assert any(code == 1 for b in RUN if b.lang == "bash" for _, code in commands(b.body))


def test_every_command_block_is_run_or_says_why_not():
    silent = [b.id for b in ALL if b.is_command and b.not_run is None and b.lang not in ("bash", "python")]
    assert not silent, f"command blocks neither run (```bash / ```python) nor marked <!-- not run: reason -->: {silent}"
    empty = [b.id for b in ALL if b.not_run is not None and len(b.not_run) < 10]
    assert not empty, f"a not-run block must say why: {empty}"


def test_the_excerpt_check_tells_a_real_output_from_another():
    out = "score λ_min(SΛS) = 0.0001931  FAIL   rank 23/23\n┃ lidar.rot_y │ 0.0394 deg │ 0.05 deg │ 0.79 │ ok ┃\n"
    assert excerpt_lines_found("score λ_min(SΛS) = 0.0001931  FAIL\n lidar.rot_y  0.0394 deg  0.05 deg  0.79  ok", out)[1] == []
    assert excerpt_lines_found("score λ_min(SΛS) = 0.0002  PASS", out)[1] != []
    assert excerpt_lines_found("lidar.rot_y  0.05 deg  0.05 deg", out)[1] == []  # within a factor of 2
    assert excerpt_lines_found("lidar.rot_y  0.5 deg", out)[1] != []
    assert excerpt_lines_found("lidar.rot_y  0.0394 cm", out)[1] != []
    assert excerpt_lines_found("12 passed in 9.5 s", "12 passed in 1.2 s")[1] == []
    assert excerpt_lines_found("12 passed in 9.5 s", "2 passed in 1.2 s")[1] != []


@pytest.mark.slow
@pytest.mark.parametrize("block", [pytest.param(b, id=b.id, marks=[pytest.mark.montecarlo] if "excite validate" in b.body else [])
                                   for b in RUN])
def test_block_runs_as_written(block: Block, workdir: Path):
    printed = []
    if block.lang == "python":
        res = subprocess.run([sys.executable, "-c", block.body], cwd=workdir, env=_env(), capture_output=True,
                             text=True, timeout=TIMEOUT_S)
        assert res.returncode == 0, res.stderr[-3000:]
        printed.append(res.stdout + res.stderr)
    for command, code in commands(block.body) if block.lang == "bash" else []:
        if "../shared/data" in command and not SHARED.joinpath("data").is_dir():
            pytest.skip("needs ../shared/data (excite data fetch --all)")
        if command.startswith("excite serve") and code == 0:
            printed.append(_serve(command, workdir))
            continue
        res = _run(command, workdir)
        assert res.returncode == code, f"{command}\nstdout:\n{res.stdout[-3000:]}\nstderr:\n{res.stderr[-3000:]}"
        assert "Traceback" not in res.stderr
        printed.append(res.stdout + res.stderr)
        for arg in shlex.split(command):
            if arg.endswith(".png") and "--plot" in command:
                assert (workdir / arg).read_bytes()[:4] == b"\x89PNG"
            if arg.endswith(".xml") and "--junit" in command:
                assert (workdir / arg).read_text().startswith("<?xml")
    if block.excerpt is not None:
        n, missing = excerpt_lines_found(block.excerpt, "\n".join(printed))
        assert len(missing) <= n // 4, f"{block.id}: the published output differs from what it prints:\n" + \
            "\n".join(missing) + "\n--- printed:\n" + "\n".join(printed)[-4000:]


def test_files_the_examples_use_are_in_git():
    """A fresh clone has every repository file the examples name (untracked files would pass here
    and fail there), and the pictures the pages show are small."""
    if not (REPO / ".git").exists():
        pytest.skip("not a git checkout")
    tracked = set(subprocess.run(["git", "ls-files"], cwd=REPO, capture_output=True, text=True,
                                 check=True).stdout.splitlines())

    def in_repo(arg: str) -> bool:
        return (REPO / arg).is_file() and REPO.resolve() in (REPO / arg).resolve().parents

    named = set()
    for b in RUN:
        if b.lang == "bash":
            for command, _ in commands(b.body):
                named |= {a for a in shlex.split(command) if in_repo(a)}
        else:
            named |= {a for a in re.findall(r'"([^"]+)"', b.body) if in_repo(a)}
    for page in PAGES:
        for target in re.findall(r"\]\(([^)#\s]+\.(?:png|yaml|md))\)", page.read_text()):
            path = (page.parent / target).resolve()
            if path.is_file() and REPO.resolve() in path.parents:
                named.add(str(path.relative_to(REPO.resolve())))
    assert named, "no repository files named by the examples?"
    assert named <= tracked, f"not committed: {sorted(named - tracked)}"
    for image in (n for n in named if n.endswith(".png")):
        assert (REPO / image).stat().st_size < 300_000, f"{image} is over 300 KB"
