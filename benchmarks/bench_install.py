"""A fresh install, timed: a new virtual environment, ``pip install`` of this checkout with empty
caches, then the first ``excite score`` and the ones after it.

    python benchmarks/bench_install.py [--runs 5]

1. ``python -m venv`` in a temporary folder;
2. ``pip install --no-cache-dir .`` (the dependencies from the index pip is configured with, excite
   built from this checkout: its native module compiled by setuptools with the system compiler);
3. the first ``excite score trajectories/figure_eight_control.csv`` in that environment, with
   every cache empty (``EXCITE_CACHE_DIR``, ``XDG_CACHE_HOME``, ``MPLCONFIGDIR`` and ``HOME`` in
   new folders): nothing is compiled at run time;
4. ``--runs`` more of the same command (caches as the first one left them) and of
   ``excite --help``, each a fresh process.

Wall times, with the load average before and after (benchmarks/results.py). The install's wall
time depends on the index (here a local wheel store) and on the machine's other work.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from results import Session, spread  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
ROUTE = "trajectories/figure_eight_control.csv"


def timed(cmd: list[str], env: dict[str, str], cwd: Path = REPO) -> float:
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    session = Session()
    with tempfile.TemporaryDirectory(prefix="excite-install-") as tmp:
        root = Path(tmp)
        home = root / "home"
        for d in ("home", "cache", "xdg", "mpl"):
            (root / d).mkdir()
        env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "EXCITE_", "VIRTUAL_ENV"))}
        env.update(HOME=str(home), EXCITE_CACHE_DIR=str(root / "cache"), XDG_CACHE_HOME=str(root / "xdg"),
                   MPLCONFIGDIR=str(root / "mpl"), PIP_NO_CACHE_DIR="1")
        venv = root / "venv"
        t_venv = timed([sys.executable, "-m", "venv", str(venv)], env, root)
        pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "--no-cache-dir", "--quiet"]
        t_pip = timed([*pip, str(REPO)], env, root)
        excite = str(venv / "bin" / "excite")
        t_first = timed([excite, "score", ROUTE], env)
        print(f"venv {t_venv:.1f} s; pip install {t_pip:.1f} s; first `excite score {ROUTE}` {t_first:.2f} s; "
              f"together {t_venv + t_pip + t_first:.1f} s")
        cached = list((root / "cache").rglob("*"))
        print(f"files in EXCITE_CACHE_DIR after the first score: {len(cached)}")
        score = [timed([excite, "score", ROUTE], env) for _ in range(args.runs)]
        helps = [timed([excite, "--help"], env) for _ in range(args.runs)]
        print(f"`excite score` after it: {statistics.median(score):.3f} s ({min(score):.3f}–{max(score):.3f}); "
              f"`excite --help`: {statistics.median(helps):.3f} s ({min(helps):.3f}–{max(helps):.3f})")
        figures = {"venv_s": round(t_venv, 2), "pip_install_s": round(t_pip, 1), "first_score_s": round(t_first, 2),
                   "install_and_first_score_s": round(t_venv + t_pip + t_first, 1),
                   "cache_files_after_first_score": len(cached), "score_after_s": spread(score),
                   "help_s": spread(helps)}
    path = session.record("install", figures, note=f"new venv, pip install --no-cache-dir of the checkout, empty "
                          f"caches; `excite score {ROUTE}` and `excite --help` as fresh processes")
    print(f"load average after: {os.getloadavg()}; figures: {path}")


if __name__ == "__main__":
    main()
