"""``excite optimize --drivable``: the plan a person drives, and what the driver gets."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from .app import console


def write_drivable(out: Path, built: Any, site: Any, rig: Any, report: Any, robust: Any,
                   extra: dict[str, Any] | None = None) -> list[Path]:
    """plan.json, cones.geojson, sheet.pdf, sheet.png, the drive as instructed (control.csv,
    maneuver.tum, waypoints.csv) and report.json (the full evaluator's report with the plan's
    robust scores) in ``out``."""
    from ..io.routes import write_control_csv, write_tum, write_waypoints_csv
    from ..motion.vehicle import drive
    from ..plan.drivable.plan import cones_geojson
    from ..plan.drivable.sheet import sheet

    out.mkdir(parents=True, exist_ok=True)
    timed = built.timed()
    traj = drive(timed.profile, rig.suspension)
    paths = [out / "plan.json", out / "cones.geojson", out / "sheet.pdf", out / "sheet.png"]
    paths[0].write_text(json.dumps(built.plan.to_dict(), indent=2))
    paths[1].write_text(json.dumps(cones_geojson(built, site.origin), indent=1))
    notes = [f"score {report.score:.3g}; 10th percentile over {robust.scores.size} drives by the driver model "
             f"{robust.low:.3g} ({100 * robust.ratio:.0f} % of it)"]
    paths[2].write_bytes(sheet(built, site, "pdf", notes=notes))
    paths[3].write_bytes(sheet(built, site, "png", notes=notes))
    paths += [write_control_csv(timed.profile, out / "control.csv"), write_tum(traj, out / "maneuver.tum"),
              write_waypoints_csv(traj, out / "waypoints.csv")]
    rep = report.to_dict()
    rep["drivable"] = {"plan": built.plan.to_dict(), "instructions": built.instructions,
                       "robust": robust.to_dict(), **(extra or {})}
    (out / "report.json").write_text(json.dumps(rep, indent=2))
    paths.append(out / "report.json")
    return paths


def run_drivable(out: Path, rig_name: str, duration: float, site: Any, seed: int, budget_s: float,
                 plan_file: Path | None, speed_max: float | None, draws: int, scene_ref: str | None = None) -> None:
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ..plan.drivable.plan import build, read_plan
    from ..plan.drivable.robust import robust_scores
    from ..plan.drivable.search import DrivableSettings, Scorer, optimize_drivable, safe_speed_mps
    from ..plan.settings import vehicle_limits
    from ..rig.config import load_rig
    from ..errors import OptimizeError
    from . import seeing

    rig = load_rig(rig_name)
    scene = seeing.load(scene_ref)
    seeing.warn_blind(rig, scene)
    settings = DrivableSettings(duration_s=duration, site=site, seed=seed, time_budget_s=max(budget_s, 1.0),
                                speed_max_mps=speed_max, draws=draws, scene=scene)
    scorer = Scorer(rig, scene)
    c = console()
    if plan_file is not None:
        from ..motion.vehicle import drive

        plan = read_plan(plan_file)
        limits = vehicle_limits(rig, settings.limits)
        safe, straight = safe_speed_mps(site, limits)
        for i, e in enumerate(plan.elements):
            v = e.params.get("speed_mps", 0.0)
            if v > safe + 1e-9:
                raise OptimizeError(f"{plan_file}: elements[{i}].params.speed_mps {v:.3g} m/s is above the lot's safe "
                                    f"speed {safe:.3g} m/s (the fastest a car reaches and stops from again along "
                                    f"its longest straight, {straight:.0f} m)")
        built = build(plan, limits)
        from ..plan.drivable.plan import violations

        bad = violations(built, built.timed(), site)
        if bad:
            raise OptimizeError(f"{plan_file}: " + "; ".join(bad))
        rep = scorer(drive(built.timed().profile, rig.suspension))
        robust = robust_scores(built.course, rig, limits, draws, rep.score, seed, settings.driver,
                               duration_s=plan.duration_s, evaluate=scorer)
        extra: dict[str, Any] = {}
    else:
        from ..plan.drivable.search import check_problem

        check_problem(site, vehicle_limits(rig, settings.limits), speed_max)  # refused before the bar starts
        with Progress(TextColumn("[bold]{task.fields[phase]:<8}"), BarColumn(),
                      TextColumn("best {task.fields[best]}  {task.fields[detail]}"), TimeElapsedColumn(),
                      console=c, transient=False) as bar:
            task = bar.add_task("drivable", total=settings.time_budget_s, phase="start", best="—", detail="")

            def on_progress(p) -> None:
                bar.update(task, completed=settings.time_budget_s if p.phase == "done" else
                           min(p.elapsed_s, settings.time_budget_s), phase=p.phase,
                           best=f"{p.best:.4g}" if p.best else "—", detail=p.detail)

            res = optimize_drivable(rig, settings, progress=on_progress)
        built, rep, robust = res.built, res.report, res.robust
        extra = {"candidates": res.rows, "design": res.design, "timings_s": res.timings_s, "elapsed_s": res.elapsed_s}
        for r in res.rows:
            c.print(f"  {r['plan']:<40} score {r['score']:.4g}  10th percentile {r['score_quantile']:.4g}"
                    + ("  ◀" if r["chosen"] else ""))
    for i, text in enumerate(built.instructions):
        c.print(f"{i + 1}. {text}", markup=False, highlight=False)
    where = seeing.line(rep.scene)
    if where is not None:
        c.print(where)
    c.print(f"score {rep.score:.4g}; 10th percentile over {robust.scores.size} drives by the driver model "
            f"{robust.low:.4g} ({100 * robust.ratio:.0f} % of it); {len(built.cones)} cones")
    for p in write_drivable(out, built, site, rig, rep, robust, extra):
        c.print(f"wrote {p}")
