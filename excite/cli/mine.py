"""``excite mine``: the windows of long logs that best determine the calibration (logic in
:mod:`excite.fleet.mine`)."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer

from . import seeing
from .app import app, console

if TYPE_CHECKING:
    from ..fleet import mine as miner


class ProgressBar:
    """A progress bar on stderr (tasks done / total, time spent, time left), shown from the first
    finished task on: an engine that fails to start leaves only its one-line error."""

    def __init__(self, what: str, total: int):
        from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn,
                                   TimeRemainingColumn)

        self._bar = Progress(TextColumn(what), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                             TextColumn("ETA"), TimeRemainingColumn(), TextColumn("{task.description}"),
                             console=console(stderr=True), transient=True)
        self._task = self._bar.add_task("", total=total)
        self._started = False

    def advance(self, description: str) -> None:
        if not self._started:
            self._bar.start()
            self._started = True
        self._bar.update(self._task, advance=1, description=description)

    def __enter__(self) -> "ProgressBar":
        return self

    def __exit__(self, *_: object) -> None:
        if self._started:
            self._bar.stop()


def _table(title: str, windows: list[miner.Window], n_params: dict[str, int]):
    from rich.table import Table

    t = Table(title=title, title_justify="left")
    for col, kw in (("#", {"justify": "right"}), ("log", {"overflow": "fold", "ratio": 1}),
                    ("window [s]", {}), ("length", {"justify": "right"}), ("score", {"justify": "right"}),
                    ("exact", {"justify": "right"}), ("determines", {"justify": "right"}),
                    ("misses (σ > target)", {"overflow": "fold", "ratio": 1})):
        t.add_column(col, **kw)
    for i, w in enumerate(windows, 1):
        n = n_params[w.log]
        misses = ", ".join(w.misses[:4]) + (f" … {len(w.misses) - 4} more" if len(w.misses) > 4 else "")
        t.add_row(str(i), w.log, f"{w.start_s:.1f} – {w.end_s:.1f}", f"{w.duration_s:.0f} s", f"{w.score:.3g}",
                  "—" if w.confirmed_score is None else f"{w.confirmed_score:.3g}",
                  f"{n - len(w.misses)}/{n}", misses or "—")
    return t


@app.command()
def mine(
    logs: Annotated[list[str], typer.Argument(help="Logs: route files, bags, folders, globs, routes manifests and URLs.")],
    window: Annotated[float, typer.Option(help="Length of the windows ranked [s] (rounded half up to whole chunks; at most the log).")] = 120.0,
    min_score: Annotated[Optional[float], typer.Option(
        help="Also find each log's shortest window whose score reaches this.")] = None,
    targets: Annotated[bool, typer.Option(
        "--targets", help="Also find each log's shortest window that brings every parameter within its target.")] = False,
    rig: Annotated[str, typer.Option(help="Rig of the logs given directly (and of manifest routes whose "
                                          "manifest names none).")] = "robotaxi",
    chunk: Annotated[float, typer.Option(help="Window resolution [s]: windows start and end on chunks of this length.")] = 10.0,
    per_log: Annotated[int, typer.Option(help="Non-overlapping best windows listed per log.")] = 1,
    json_out: Annotated[Optional[Path], typer.Option("--json", help="Write the windows and each log's outcome as JSON here.")] = None,
    csv_out: Annotated[Optional[Path], typer.Option("--csv", help="Write the ranked windows as CSV here (log,start_s,end_s,score,…).")] = None,
    crop: Annotated[Optional[Path], typer.Option(help="Write the winning window's crop into this folder "
                                                      "(TUM poses; for a bag also the bag cut to the window).")] = None,
    scheduler: Annotated[Optional[str], typer.Option(
        help="Dask scheduler to run on (tcp://host:8786; default $EXCITE_DASK_SCHEDULER, else local processes).")] = None,
    jobs: Annotated[Optional[int], typer.Option(help="Local processes (default: one per core).")] = None,
    topic: Annotated[Optional[str], typer.Option(help="Trajectory source of the bags given directly.")] = None,
    imu_topic: Annotated[Optional[str], typer.Option(help="IMU topic of the bags given directly.")] = None,
    scene: Annotated[Optional[str], typer.Option(
        help=seeing.HELP + " Applies to the logs given directly and to manifest routes whose manifest names none.")] = None,
) -> None:
    """Rank the windows of LOGS that best determine the rig's calibration; exit 1 when a log
    cannot be read or (with --min-score/--targets) no log reaches the goal."""
    from ..fleet import batch as gate
    from ..fleet import mine as miner
    from ..errors import ExciteError

    for name, value in (("--window", window), ("--chunk", chunk)):
        if not (math.isfinite(value) and value > 0):
            raise ExciteError(f"{name} must be a duration > 0 s, got {value:g}")
    if per_log < 1:
        raise ExciteError(f"--per-log must be ≥ 1, got {per_log}")
    if min_score is not None and targets:
        raise ExciteError("--min-score and --targets are two goals: give one")
    if min_score is not None and not (math.isfinite(min_score) and min_score > 0):
        raise ExciteError(f"--min-score must be a number > 0, got {min_score:g}")
    goal = miner.Goal(min_score) if min_score is not None or targets else None
    specs = gate.collect(logs, rig=rig, topic=topic, imu_topic=imu_topic, scene=scene)
    tasks = [miner.Task(s, window, goal, per_log, chunk) for s in specs]
    t0 = time.perf_counter()
    with ProgressBar("mining", len(tasks)) as bar:
        results = miner.mine_logs(tasks, jobs=jobs, scheduler=scheduler, on_result=lambda r, _: bar.advance(r.log))
    total_s = time.perf_counter() - t0
    best, shortest = miner.ranked(results)
    n_params = {s.name: len(gate.cached_rig(s.rig).scored) for s in specs if s.error is None}
    out = console()
    out.print(_table(f"best windows of {window:g} s (whole {chunk:g} s chunks)", best, n_params))
    if goal is not None:
        if shortest:
            out.print(_table(f"shortest windows reaching {goal.describe()}", shortest, n_params))
        for r in results:
            if r.error is None and r.shortest is None:
                out.print(f"[yellow]{r.log}[/]: never reaches {goal.describe()}; the whole log scores "
                          f"{r.whole_score:.3g}")
    for where in sorted({seeing.line(r.scene) for r in results if r.scene is not None}):
        out.print(f"seen in {where}", markup=False, highlight=False)
    n_windows = sum(r.windows_evaluated for r in results)
    errors = [r for r in results if r.error is not None]
    for r in errors:
        out.print(f"[red]{r.log}[/]: {r.error}", overflow="fold")
    out.print(f"{len(results) - len(errors)} logs mined, {n_windows} windows scored in {total_s:.1f} s")
    if json_out is not None:
        import json

        gate.write_text(json_out, json.dumps(miner.results_json(results, window, goal), indent=2))
    if csv_out is not None:
        gate.write_text(csv_out, miner.windows_csv(shortest + best if goal is not None else best))
    winner = (shortest or best)[:1] if goal is not None else best[:1]
    if crop is not None and winner:
        for f in miner.write_crop(winner[0], next(s for s in specs if s.path == winner[0].path), crop):
            out.print(f"crop: {f}")
    if errors or (goal is not None and not shortest):
        raise typer.Exit(1)
