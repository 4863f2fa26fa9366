"""The product speaks of itself: no issue numbers, sessions or rounds of work in the code, the
tests or the documentation, and no dated measurement logs in the pages (a figure's history is the
git history of its file in benchmarks/results/, the project's in the changelog and the commits)."""

from __future__ import annotations

import re

from helpers import REPO

HISTORY = re.compile(r"issue [0-9]|session [0-9]|round (two|three)", re.I)
DATE = re.compile(r"\b20[0-9]{2}-[01][0-9]-[0-3][0-9]\b")
TEXT = (".py", ".md", ".js", ".html", ".css", ".yaml", ".yml", ".toml", ".txt")


def _files(*tops: str):
    for top in tops:
        path = REPO / top
        for f in ([path] if path.is_file() else path.rglob("*")):
            if f.is_file() and f.suffix in TEXT and "__pycache__" not in f.parts and f.name != "test_history.py":
                yield f


def test_no_history_talk_in_code_tests_or_docs():
    found = [f"{f.relative_to(REPO)}:{n}: {line.strip()[:100]}"
             for f in _files("excite", "api", "tests", "docs", "README.md")
             for n, line in enumerate(f.read_text(errors="replace").splitlines(), 1) if HISTORY.search(line)]
    assert not found, "\n".join(found)


def test_no_dated_logs_in_the_pages():
    found = [f"{f.relative_to(REPO)}:{n}: {line.strip()[:100]}"
             for f in _files("docs", "README.md") if f.suffix == ".md"
             for n, line in enumerate(f.read_text().splitlines(), 1) if DATE.search(line)]
    assert not found, "\n".join(found)
