"""``excite optimize``: plan the maneuver that maximises the score, within a lot and limits."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer

from ..core.bounds import OPTIMIZE as _B
from ..errors import ExciteError
from .app import app, console

if TYPE_CHECKING:
    from ..plan import OptimizeResult


_WRITE_S = 0.4  # kept from the budget for the table and the output files (0.25 s measured at load 5)


def _process_age_s() -> float:
    """Seconds since this process started (Linux /proc; 0 where unknown)."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return max(uptime - start_ticks / os.sysconf("SC_CLK_TCK"), 0.0)
    except (OSError, ValueError, IndexError):
        return 0.0


def _num(v, fmt: str = ".4g") -> str:
    return "—" if v is None else format(v, fmt)


def comparison_table(result: OptimizeResult):
    from rich.markup import escape
    from rich.table import Table

    t = Table(title="Comparison (full evaluator; every row passed the same limit and lot check "
                    "unless marked)", title_justify="left")
    for col, just in (("candidate", "left"), ("kind", "left"), ("score λ_min", "right"),
                      ("worst σ/target", "right"), ("log det", "right"), ("tr M⁻¹", "right"),
                      ("rot. exc. λ_min", "right"), ("result ÷", "right"), ("feasible", "left"),
                      ("first violation", "left")):
        t.add_column(col, justify=just)
    for r in result.comparison:
        ratio = "—" if r.get("ratio") is None else f"{r['ratio']:.2f}×"
        feas = "[green]yes[/]" if r["feasible"] else "[red]no[/]"
        why = "" if r["feasible"] else escape(r["violations"][0][:60])
        name = f"[bold]{escape(r['name'])}[/] ◀" if r.get("result") else escape(r["name"])
        t.add_row(name, r["kind"], _num(r.get("score")), _num(r.get("worst_sigma_ratio"), ".3g"),
                  _num(r.get("log_det"), ".1f"), _num(r.get("trace_inv"), ".3g"),
                  _num(r.get("rotation_excitation"), ".3g"), ratio, feas, why)
    return t


def write_outputs(result: OptimizeResult, out: Path, origin: tuple[float, float] | None = None) -> list[Path]:
    """maneuver.tum, control.csv, waypoints.csv, report.json, comparison.json in ``out`` (and
    maneuver.geojson when the lot is georeferenced: ``origin`` (lon, lat))."""
    from ..plan.site import maneuver_geojson
    from ..io.routes import write_control_csv, write_tum, write_waypoints_csv

    out.mkdir(parents=True, exist_ok=True)
    paths = [write_tum(result.trajectory, out / "maneuver.tum"),
             write_control_csv(result.profile, out / "control.csv"),
             write_waypoints_csv(result.trajectory, out / "waypoints.csv")]
    rep = result.report.to_dict()
    rep["optimization"] = {k: v for k, v in result.to_dict().items() if k not in ("report", "comparison")}
    (out / "report.json").write_text(json.dumps(rep, indent=2))
    (out / "comparison.json").write_text(json.dumps(result.comparison, indent=2))
    paths += [out / "report.json", out / "comparison.json"]
    if origin is not None:
        s = result.trajectory.sample(result.trajectory.times(10.0))
        (out / "maneuver.geojson").write_text(maneuver_geojson(s.p_W_V, s.speed, origin, "maneuver"))
        paths.append(out / "maneuver.geojson")
    return paths


@app.command()
def optimize(
    out: Annotated[Path, typer.Option("-o", "--out", help="Output folder.")],
    rig: Annotated[str, typer.Option(help="Bundled rig name or rig YAML path.")] = "robotaxi",
    duration: Annotated[float, typer.Option(help=f"Maneuver duration [s], rest to rest; range {_B['duration_s']}.")] = 90.0,
    lot: Annotated[str, typer.Option(help="The lot: XxY [m] (a rectangle, extent along x then y, centred) "
                                          "or a GeoJSON file (Polygon with keep-out holes, entry Point, "
                                          "ramp/bank/bump Polygons).")] = "80x50",
    seed: Annotated[int, typer.Option(help=f"Seed of the random candidates; range {_B['seed']}.")] = 0,
    time_budget: Annotated[float, typer.Option(
        help=f"Wall-clock budget of the whole command [s]; range {_B['time_budget_s']}.")] = 60.0,
    closed: Annotated[bool, typer.Option(help="End where it started (position and heading).")] = False,
    n_random: Annotated[int, typer.Option(help=f"Random candidates in the comparison; range {_B['n_random']}.")] = 200,
    criterion: Annotated[str, typer.Option(help="What to maximise: E (λ_min, the score), D (log det), "
                                                "A (−trace of the inverse).")] = "E",
    starts: Annotated[int, typer.Option(help="IPOPT starts (the best candidates by the model), run at once on the "
                                             "free cores or the Dask cluster; the best checked plan wins, "
                                             "after the slowest has finished; range [1, 64].")] = 1,
    scheduler: Annotated[str | None, typer.Option(help="Dask scheduler for the starts (default: "
                                                       "$EXCITE_DASK_SCHEDULER, else local processes).")] = None,
    drivable: Annotated[bool, typer.Option("--drivable", help="Plan what a person drives from cones and a sheet: "
                                           "elements (figure-eights, circles, slaloms, straight runs) placed in the "
                                           "lot, chosen by the 10th percentile of their score over the driver "
                                           "model's drives; writes plan.json, cones.geojson, sheet.pdf/png too.")] = False,
    plan: Annotated[Optional[Path], typer.Option("--plan", help="With --drivable: drive this plan.json (as written "
                                                 "or edited) instead of searching: its sheet, cones and scores.")] = None,
    speed_max: Annotated[Optional[float], typer.Option("--speed-max", help="With --drivable: the fastest speed the "
                                                       "instructions may ask for [m/s] (at most the lot's safe "
                                                       "speed).")] = None,
    draws: Annotated[int, typer.Option(help="With --drivable: drives of the driver model per plan in the robust "
                                            "choice; range [5, 1000].")] = 30,
    scene: Annotated[Optional[str], typer.Option(help="With --drivable: plan in this scene (in the lot's frame): "
                                                      "a scene file (.geojson, .ply, .obj, .stl, .pcd, .las, "
                                                      ".laz) or a bundled scene's name (excite scene list); every "
                                                      "drive the search scores is seen by the rig's lidars in it, "
                                                      "so where and at what heading each element goes is chosen "
                                                      "by what they see there.")] = None,
    compile_only: Annotated[bool, typer.Option("--compile-only", help="Compile the optimizer's model for this "
                                               "rig and duration with the C compiler, score the "
                                               "reference maneuvers for this lot, both into the cache "
                                               "($EXCITE_CACHE_DIR), and exit (a Docker image's build step).")] = False,
) -> None:
    """Plan the drive that determines the worst-determined calibration direction best.

    The result is the best drive, among everything this run has seen, that passed the limit and
    lot check. Ctrl-C keeps the best checked drive found so far and writes it.
    """
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ..plan import OptimizeSettings, optimize as run_optimize
    from ..plan import Progress as OptProgress
    from ..plan.site import parse_lot
    from ..rig.config import load_rig

    if out.exists() and not out.is_dir():
        raise ExciteError(f"-o/--out: {out} exists and is not a folder")
    site = parse_lot(lot)
    if drivable or plan is not None:
        from .drivable import run_drivable

        run_drivable(out, rig, duration, site, seed, time_budget - _process_age_s() - _WRITE_S, plan, speed_max,
                     draws, scene)
        return
    if scene is not None:
        raise typer.BadParameter("plans in a scene with --drivable (or --plan); the free-form optimizer plans blind",
                                 param_hint="--scene")
    OptimizeSettings(time_budget_s=time_budget, starts=starts)  # validate the budget as given
    if compile_only:
        from ..plan.compiled import cache_dir
        from ..plan.pipeline import prepare

        r = load_rig(rig)
        done = prepare(r, OptimizeSettings(duration_s=duration, site=site, closed=closed, criterion=criterion))
        console().print(f"the optimizer's model for {r.name}, {duration:g} s: {done['mode']} "
                        f"({', '.join(f'{k} {v:.1f} s' for k, v in done['seconds'].items()) or 'cached'}), "
                        f"the reference maneuvers {done['references']}, in {cache_dir()}")
        return
    # the budget bounds the whole command: start-up so far and writing the files come off it
    left = time_budget - _process_age_s() - _WRITE_S
    settings = OptimizeSettings(duration_s=duration, site=site, seed=seed, time_budget_s=max(left, 0.5),
                                closed=closed, n_random=n_random, criterion=criterion, starts=starts,
                                scheduler=scheduler)
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
                      TextColumn("it {task.fields[it]:>4}  model {task.fields[score]}  "
                                 "violation {task.fields[viol]}"), TimeElapsedColumn(),
                      console=out_console, transient=False) as bar:
            task = bar.add_task("optimize", total=settings.time_budget_s, phase="start", it=0,
                                score="—", viol="—")

            def on_progress(p: OptProgress) -> None:
                done = settings.time_budget_s if p.phase == "done" else min(p.elapsed_s, settings.time_budget_s)
                bar.update(task, completed=done, phase=p.phase, it=p.iteration,
                           score=f"{p.score:.4g}", viol=f"{p.constraint_violation:.2g}")

            result = run_optimize(r, settings, progress=on_progress, should_stop=lambda: interrupted["flag"])
    finally:
        signal.signal(signal.SIGINT, old)
    out_console.print(comparison_table(result))
    out_console.print(f"status [bold]{result.status}[/] ({result.starts_converged} of {result.starts} IPOPT "
                      f"start{'s' if result.starts != 1 else ''} converged; the best: {result.ipopt_status}, "
                      f"{result.iterations} iterations); result: {result.source}; {result.elapsed_s:.1f} s of the "
                      f"{time_budget:g} s budget; score {result.report.score:.4g}"
                      + (f"\n{result.message}" if result.message else ""))
    for p in write_outputs(result, out, site.origin):
        out_console.print(f"wrote {p}")
