"""``excite batch``: the CI gate over many routes (logic in :mod:`excite.fleet.batch`)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Optional

from typing import TYPE_CHECKING

import typer

from . import seeing
from .app import app, console

if TYPE_CHECKING:
    from ..fleet import batch as gate

_MAX_SHOWN = 4  # failing parameters listed per route in the table


def _table(results: list[gate.RouteResult]):
    from rich.markup import escape
    from rich.table import Table

    rigs = sorted({r.rig for r in results})
    one_rig = len(rigs) == 1
    scenes = {seeing.line(r.scene) for r in results if r.status != "error"}
    one_scene = len(scenes) <= 1
    title = "excite batch" + (f", rig {rigs[0]}" if one_rig else "")
    if len(scenes) == 1 and None not in scenes:
        title += f" in {escape(scenes.pop())}"
    t = Table(title=title, title_justify="left")
    t.add_column("route", overflow="fold", ratio=1)
    if not one_rig:
        t.add_column("rig", overflow="fold")
    if not one_scene:
        t.add_column("scene", overflow="fold")
    t.add_column("score", justify="right")
    t.add_column("result")
    t.add_column("not met (σ > bound) / error", overflow="fold", ratio=1)
    for r in results:
        verdict = {"passed": "[green]pass[/]", "failed": "[red]FAIL[/]", "error": "[red]ERROR[/]"}[r.status]
        shown = [f.short() for f in r.failures[:_MAX_SHOWN]]
        if len(r.failures) > _MAX_SHOWN:
            shown.append(f"… {len(r.failures) - _MAX_SHOWN} more (JUnit/--json list all)")
        detail = r.error if r.error is not None else "\n".join(shown + [f"[yellow]warning: {escape(w)}[/]" for w in r.warnings])
        rig = [] if one_rig else [r.rig]
        if not one_scene:  # the file's name and the digest's start: the title names one in full
            rig.append("—" if r.scene is None else escape(f"{Path(r.scene['name']).name} ({r.scene['digest'][:8]})"))
        t.add_row(r.name, *rig, "—" if r.score is None else f"{r.score:.3g}", verdict, detail or "")
    return t


@app.command()
def batch(
    paths: Annotated[list[str], typer.Argument(help="Route files, folders, globs, routes manifests (.yaml) and URLs (https://…, s3://…).")],
    rig: Annotated[str, typer.Option(help="Rig of the routes given directly (and of manifest routes "
                                          "whose manifest names none).")] = "robotaxi",
    min_score: Annotated[Optional[float], typer.Option(
        help="Routes given directly pass when their score reaches this; without it, when every "
             "parameter is within its target. Manifest routes carry their own expectations.")] = None,
    junit: Annotated[Optional[Path], typer.Option(help="Write JUnit XML here (one test case per route).")] = None,
    json_out: Annotated[Optional[Path], typer.Option("--json", help="Write every result and report as JSON here.")] = None,
    jobs: Annotated[Optional[int], typer.Option(help="Parallel processes (default: one per core).")] = None,
    topic: Annotated[Optional[str], typer.Option(
        help="Trajectory source of the bags given directly (manifest routes name their own).")] = None,
    imu_topic: Annotated[Optional[str], typer.Option(help="IMU topic of the bags given directly.")] = None,
    scheduler: Annotated[Optional[str], typer.Option(
        help="Dask scheduler to run on (tcp://host:8786; default $EXCITE_DASK_SCHEDULER, else local processes).")] = None,
    scene: Annotated[Optional[str], typer.Option(
        help=seeing.HELP + " Applies to the routes given directly and to manifest routes whose manifest names none.")] = None,
) -> None:
    """Evaluate routes against their expectations; exit 1 when any route fails or cannot be read."""
    from ..fleet import batch as gate
    from .mine import ProgressBar

    specs = gate.collect(paths, rig=rig, min_score=min_score, topic=topic, imu_topic=imu_topic, scene=scene)
    t0 = time.perf_counter()
    with ProgressBar("scoring", len(specs)) as bar:
        results = gate.run(specs, jobs=jobs, keep_reports=json_out is not None, scheduler=scheduler,
                           on_result=lambda r: bar.advance(f"{r.name}: {r.status}"))
    total_s = time.perf_counter() - t0
    out_console = console()
    out_console.print(_table(results))
    n_fail = sum(r.status == "failed" for r in results)
    n_err = sum(r.status == "error" for r in results)
    n_pass = len(results) - n_fail - n_err
    colour = "green" if n_fail + n_err == 0 else "red"
    out_console.print(f"[{colour}]{n_pass} passed, {n_fail} failed, {n_err} errors[/] in {total_s:.1f} s")
    for r in results:
        if r.advice:
            out_console.print(f"[bold]{r.name}[/]: what it takes")
            for a in r.advice[:2]:
                out_console.print(f"  {a}", overflow="fold")
    if junit is not None:
        gate.write_text(junit, gate.junit_xml(results, total_s))
    if json_out is not None:
        gate.write_text(json_out, gate.dumps(results))
    if n_fail + n_err:
        raise typer.Exit(1)
