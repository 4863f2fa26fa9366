"""The Benchmarks page shows the current figure of every benchmark: each script in
``benchmarks/bench_*.py`` has a results file that names it in its command, each results file
belongs to a script that exists, and the page generated from them has a section with every
figure of every file and no script left without one."""

from __future__ import annotations

import importlib.util
import json
import re

from helpers import REPO

BENCH = REPO / "benchmarks"
SCRIPT = re.compile(r"benchmarks/(bench_[a-z0-9_]+\.py)\b")


def _results() -> list[dict]:
    return [json.loads(f.read_text()) for f in sorted((BENCH / "results").glob("*.json"))]


def _page() -> str:
    spec = importlib.util.spec_from_file_location("docs_hooks_for_test", REPO / "docs" / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    return hooks._benchmarks_markdown()


def test_every_results_file_says_what_produced_it():
    for d in _results():
        name = d.get("benchmark")
        assert name and (BENCH / "results" / f"{name}.json").is_file(), name
        assert d["figures"], f"{name}: no figures"
        assert SCRIPT.search(d["command"]), f"{name}: its command names no benchmark script: {d['command']!r}"
        assert d["commit"]["sha"] and d["machine"]["cpu"] and d["machine"]["cores"], name
        assert len(d["load_average"]["before"]) == 3 and len(d["load_average"]["after"]) == 3, name


def test_every_benchmark_script_has_current_figures_and_every_figure_a_script():
    scripts = {p.name for p in BENCH.glob("bench_*.py")}
    recorded = {SCRIPT.search(d["command"]).group(1) for d in _results()}
    assert not sorted(scripts - recorded), f"benchmarks without a results file: {sorted(scripts - recorded)}"
    assert not sorted(recorded - scripts), f"results of scripts that no longer exist: {sorted(recorded - scripts)}"


def test_the_page_shows_every_figure_of_every_results_file():
    page = _page()
    assert "not recorded yet" not in page
    for d in _results():
        section = page.split(f"\n## {d['benchmark']}\n", 1)
        assert len(section) == 2, f"no section for {d['benchmark']}"
        body = section[1].split("\n## ", 1)[0]
        for key in d["figures"]:
            assert f"| `{key}` |" in body, f"{d['benchmark']}: figure {key} not on the page"
        assert d["command"] in body and d["commit"]["sha"][:10] in body
        assert str(d["load_average"]["before"]) in body
