"""``excite optimize``: plan the maneuver that maximises the score, within a lot and limits."""

from __future__ import annotations

import json
import re
import signal
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ..bounds import OPTIMIZE as _B
from ..errors import ExciteError
from . import app, console

if TYPE_CHECKING:
    from ..optimize import OptimizeResult

def parse_lot(text: str) -> tuple[float, float]:
    """``"80x50"`` → (80.0, 50.0): extent along x, then along y [m]."""
    m = re.fullmatch(r"\s*([0-9.]+)\s*[xX×]\s*([0-9.]+)\s*", text)
    if not m:
        raise ExciteError(f"--lot: expected XxY in metres (extent along x, then y) such as 80x50, got {text!r}")
    return float(m.group(1)), float(m.group(2))


def comparison_table(result: OptimizeResult):
    from rich.markup import escape
    from rich.table import Table

    t = Table(title="Comparison (re-scored by the full evaluator)", title_justify="left")
    for col, just in (("candidate", "left"), ("kind", "left"), ("score λ_min", "right"),
                      ("optimized ÷", "right"), ("feasible", "left"), ("first violation", "left")):
        t.add_column(col, justify=just)
    for r in result.comparison:
        ratio = "—" if r.get("ratio") is None else f"{r['ratio']:.2f}×"
        feas = "[green]yes[/]" if r["feasible"] else "[red]no[/]"
        why = "" if r["feasible"] else escape(r["violations"][0][:60])
        t.add_row(escape(r["name"]), r["kind"], f"{r['score']:.4g}", ratio, feas, why)
    return t


def write_outputs(result: OptimizeResult, out: Path) -> list[Path]:
    """maneuver.tum, control.csv, waypoints.csv, report.json, comparison.json in ``out``."""
    from ..routes import write_control_csv, write_tum, write_waypoints_csv

    out.mkdir(parents=True, exist_ok=True)
    paths = [write_tum(result.trajectory, out / "maneuver.tum"),
             write_control_csv(result.profile, out / "control.csv"),
             write_waypoints_csv(result.trajectory, out / "waypoints.csv")]
    rep = result.report.to_dict()
    rep["optimization"] = {k: v for k, v in result.to_dict().items() if k not in ("report", "comparison")}
    (out / "report.json").write_text(json.dumps(rep, indent=2))
    (out / "comparison.json").write_text(json.dumps(result.comparison, indent=2))
    return paths + [out / "report.json", out / "comparison.json"]


@app.command()
def optimize(
    out: Annotated[Path, typer.Option("-o", "--out", help="Output folder.")],
    rig: Annotated[str, typer.Option(help="Bundled rig name or rig YAML path.")] = "robotaxi",
    duration: Annotated[float, typer.Option(help=f"Maneuver duration [s], rest to rest; range {_B['duration_s']}.")] = 90.0,
    lot: Annotated[str, typer.Option(help=f"Lot size XxY [m]: extent along x, then along y; each in {_B['lot_x_m']}.")] = "80x50",
    seed: Annotated[int, typer.Option(help=f"Seed of the random candidates; range {_B['seed']}.")] = 0,
    time_budget: Annotated[float, typer.Option(help=f"Wall-clock budget of the optimization [s]; range {_B['time_budget_s']}.")] = 60.0,
    closed: Annotated[bool, typer.Option(help="End where it started (position and heading).")] = False,
    n_random: Annotated[int, typer.Option(help=f"Random candidates in the comparison; range {_B['n_random']}.")] = 200,
) -> None:
    """Plan the drive that determines the worst-determined calibration direction best.

    Ctrl-C keeps the best feasible drive found so far and writes it.
    """
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ..optimize import OptimizeSettings, optimize as run_optimize
    from ..optimize import Progress as OptProgress
    from ..rig import load_rig

    if out.exists() and not out.is_dir():
        raise ExciteError(f"-o/--out: {out} exists and is not a folder")
    w, length = parse_lot(lot)
    settings = OptimizeSettings(duration_s=duration, lot_x_m=w, lot_y_m=length, seed=seed,
                                time_budget_s=time_budget, closed=closed, n_random=n_random)
    r = load_rig(rig)
    out_console = console()
    interrupted = {"flag": False}

    def on_sigint(signum, frame):  # first Ctrl-C: stop gracefully; second: abort
        if interrupted["flag"]:
            raise KeyboardInterrupt
        interrupted["flag"] = True

    old = signal.signal(signal.SIGINT, on_sigint)
    try:
        with Progress(TextColumn("[bold]{task.fields[phase]:<9}"), BarColumn(),
                      TextColumn("it {task.fields[it]:>4}  λ_min {task.fields[score]}  "
                                 "violation {task.fields[viol]}"), TimeElapsedColumn(),
                      console=out_console, transient=False) as bar:
            task = bar.add_task("optimize", total=settings.time_budget_s, phase="start", it=0,
                                score="—", viol="—")

            def on_progress(p: OptProgress) -> None:
                done = min(p.elapsed_s, settings.time_budget_s) if p.phase in ("start", "optimize") \
                    else settings.time_budget_s
                bar.update(task, completed=done, phase=p.phase, it=p.iteration,
                           score=f"{p.score:.4g}", viol=f"{p.constraint_violation:.2g}")

            result = run_optimize(r, settings, progress=on_progress, should_stop=lambda: interrupted["flag"])
    finally:
        signal.signal(signal.SIGINT, old)
    out_console.print(comparison_table(result))
    out_console.print(f"status [bold]{result.status}[/], {result.iterations} IPOPT iterations, "
                  f"{result.elapsed_s:.1f} s (optimization {result.timings_s.get('optimize', 0):.1f} s); "
                  f"score {result.report.score:.4g}" + (f"\n{result.message}" if result.message else ""))
    for p in write_outputs(result, out):
        out_console.print(f"wrote {p}")
