"""The command line's output to a pipe or a file: at most 100 columns, cells wrapped between
words, never through one."""

from __future__ import annotations

import re
from pathlib import Path

from excite.cli.app import PIPE_WIDTH, main
from excite.rig.config import load_rig

ROUTE = Path(__file__).resolve().parents[2] / "trajectories" / "figure_eight_control.csv"


def test_a_report_to_a_pipe_fits_100_columns_and_cuts_no_word(capsys, monkeypatch):
    monkeypatch.delenv("COLUMNS", raising=False)
    assert main(["score", str(ROUTE), "--rig", "robotaxi"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert PIPE_WIDTH == 100 and max(len(line) for line in lines) <= 100
    names = {c.name for c in load_rig("robotaxi").coordinates}
    # every parameter name the tables print is whole (a cut one would be a fragment not in the rig)
    printed = set(re.findall(r"\b[a-z][a-z0-9_]*\.[a-z][a-z0-9_]*\b", out))
    assert printed and printed <= names, printed - names
    # the advice column wraps between words: each of its words is one the advice holds
    advice_words = {w for line in lines if line.startswith("│") for w in line.split("│")[-2].split()}
    assert "undetermined" in advice_words or "pitch" in advice_words
