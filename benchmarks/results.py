"""Where every benchmark writes its figures: one JSON file per benchmark in ``benchmarks/results/``.

    from results import record
    record("evaluate", {"ten_minute_warm_ms": {"median": 38.0, "range": [35.1, 47.2], "runs": 7}},
           note="the 10-minute reference drive, default rig, every coordinate estimated")

Each file holds the benchmark's current figures with what produced them: the command line, the
git commit (and whether the tree had uncommitted changes), the machine (CPU model, cores, memory),
the load average before and after, and the time. A later run of the same benchmark replaces the
file: the history of a figure is the git history of its file. The documentation's Benchmarks page
is generated from these files (``docs/gen_benchmarks.py``).

Figures are plain JSON values; a figure that is a range over several runs is written as
``{"median": m, "range": [lo, hi], "runs": n}`` with its unit in the key (``_ms``, ``_s``,
``_mib``) so the page can show it without knowing the benchmark.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Iterable

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def memory_gib() -> float | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemTotal:"):
                return round(int(line.split()[1]) / 2**20, 1)
    except OSError:
        pass
    return None


def load_average() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def commit() -> dict[str, Any]:
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True).stdout.strip()

    return {"sha": git("rev-parse", "HEAD") or None, "dirty": bool(git("status", "--porcelain", "--untracked-files=no"))}


def idle_fraction(dt: float = 0.2) -> float:
    """Fraction of the machine's CPU time that was idle over the next ``dt`` seconds."""
    def read():
        v = [int(x) for x in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
        return v[3] + v[4], sum(v)
    i0, t0 = read()
    time.sleep(dt)
    i1, t1 = read()
    return (i1 - i0) / max(1, t1 - t0)


def wait_until_idle(limit_s: float, idle: float = 0.9) -> bool:
    """Wait up to ``limit_s`` seconds until the machine's cores were at least ``idle`` idle over
    0.2 s; whether they were."""
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        if idle_fraction() >= idle:
            return True
    return False


def spread(values: Iterable[float], digits: int = 4) -> dict[str, Any]:
    """A figure measured over several runs: median, range and count."""
    v = [float(x) for x in values]
    return {"median": round(statistics.median(v), digits), "range": [round(min(v), digits), round(max(v), digits)],
            "runs": len(v)}


class Session:
    """The machine's state when a benchmark starts; :meth:`record` adds its state at the end."""

    def __init__(self) -> None:
        self.load_before = load_average()
        self.started = _dt.datetime.now(_dt.timezone.utc)

    def record(self, name: str, figures: dict[str, Any], note: str = "", command: str | None = None) -> Path:
        return record(name, figures, note=note, command=command, load_before=self.load_before,
                      started=self.started)


def record(name: str, figures: dict[str, Any], note: str = "", command: str | None = None,
           load_before: list[float] | None = None, started: _dt.datetime | None = None) -> Path:
    """Write ``benchmarks/results/<name>.json`` (replacing it) and return its path."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    now = _dt.datetime.now(_dt.timezone.utc)
    doc = {
        "benchmark": name,
        "note": note,
        "figures": figures,
        "command": command or shlex.join(["python", *([Path(sys.argv[0]).resolve().relative_to(ROOT).as_posix()]
                                                     if Path(sys.argv[0]).resolve().is_relative_to(ROOT)
                                                     else [sys.argv[0]]), *sys.argv[1:]]),
        "commit": commit(),
        "machine": {"cpu": cpu_model(), "cores": os.cpu_count(), "memory_gib": memory_gib(),
                    "python": platform.python_version(), "system": platform.system()},
        "load_average": {"before": load_before, "after": load_average()},
        "started": (started or now).isoformat(timespec="seconds"),
        "finished": now.isoformat(timespec="seconds"),
    }
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps(doc, indent=2, ensure_ascii=False) + "\n")
    return path
