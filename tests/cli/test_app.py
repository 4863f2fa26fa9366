"""The command line's output to a pipe or a file: at most 100 columns, cells wrapped between
words, never through one."""

from __future__ import annotations

import gc
import os
import re
import subprocess
import sys
from pathlib import Path

from excite.cli.app import PIPE_WIDTH, main
from excite.rig.config import load_rig

ROOT = Path(__file__).resolve().parents[2]
ROUTE = ROOT / "trajectories" / "figure_eight_control.csv"


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


def test_the_commands_own_process_imports_without_the_collector_and_freezes_what_it_imported():
    code = ("import gc\n"
            "from excite.cli import app\n"
            "app._own_process = True  # as run() sets it\n"
            "before = gc.get_freeze_count()\n"
            "with app.imports():\n"
            "    paused = not gc.isenabled()\n"
            "    import numpy\n"
            "print(paused, gc.isenabled(), before, gc.get_freeze_count() > before)")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["True", "True", "0", "True"]


def test_a_program_calling_main_keeps_its_collector_as_it_is():
    frozen = gc.get_freeze_count()
    assert main(["score", "--help"]) == 0
    assert gc.isenabled() and gc.get_freeze_count() == frozen
