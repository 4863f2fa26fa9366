"""``excite validate``: Monte Carlo check of the evaluator's predicted σ on a route."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import typer

from . import seeing
from .app import app, console

if TYPE_CHECKING:
    from ..rig.config import Rig
    from ..motion.trajectory import Trajectory
    from ..validate.monte_carlo import MonteCarloResult


def crop(traj: Trajectory, duration_s: float, rate_hz: float = 100.0) -> Trajectory:
    """The first ``duration_s`` of a drive (re-fitted from samples at ``rate_hz``, tilt kept)."""
    import numpy as np

    from ..core import so3
    from ..motion.trajectory import Trajectory
    from ..errors import ValidateError

    if duration_s >= traj.duration:
        return traj
    if duration_s <= 0:
        raise ValidateError(f"--duration must be positive, got {duration_s:g}")
    t = traj.t_start + np.arange(int(np.floor(duration_s * rate_hz)) + 1) / rate_hz
    s = traj.sample(t)
    tilt = None
    if traj.has_tilt:
        ypr = so3.yaw_pitch_roll(np.swapaxes(s.R_V_A, 1, 2))  # R_A_V = Ry(pitch)·Rx(roll)
        tilt = ypr[:, 1:3]
    out = Trajectory(t, s.R_W_V, s.p_W_V, tilt_pitch_roll=tilt, velocity=s.v_W, name=traj.name)
    out.origin = traj.origin
    return out


def with_imu_rate(rig: Rig, rate_hz: float) -> Rig:
    imu = rig.config.imu.model_dump()
    imu["update_rate"] = rate_hz
    return rig.with_config(imu=imu)


def _fmt(value: float | None, unit: str) -> str:
    from ..core.units import display_unit

    if value is None:
        return "—"
    f, _ = display_unit(unit)
    return f"{value * f:.3g}"


def print_result(res: MonteCarloResult, console: Any) -> None:
    """The Monte Carlo comparison as tables for a terminal."""
    from rich.markup import escape
    from rich.table import Table

    from ..core.units import display_unit

    rep = res.report
    n = len(res.trials)
    conf = int(round(100 * res.settings.confidence))
    where = seeing.line(rep.scene)
    console.print(f"[bold]{rep.route}[/] with rig [bold]{rep.rig}[/]" + (f" in {escape(where)}" if where else "")
                  + f": {rep.duration_s:.1f} s, "
                  f"{rep.n_keyframes} keyframes, rank {rep.rank}/{rep.rank + rep.nullity}; "
                  f"{n} trials (seed {res.settings.seed}), true offsets "
                  f"{res.settings.offset_in_targets:g} × target, {res.seconds:.0f} s")
    t = Table(title=f"Predicted (Cramér–Rao) vs Monte Carlo σ; {conf} % interval of the empirical σ",
              title_justify="left")
    for col, just in (("parameter", "left"), ("unit", "left"), ("pred. σ", "right"), ("emp. σ", "right"),
                      (f"{conf} % interval", "right"), ("emp/pred", "right"), ("bias ± s.e.", "right"),
                      ("", "left")):
        t.add_column(col, justify=just, no_wrap=True)
    for p in res.parameters:
        lo, hi = p.sigma_interval
        if p.predicted_sigma is None:
            ratio, verdict = "—", "[yellow]unobservable[/]"
        else:
            ratio = f"{p.ratio:.2f}"
            verdict = "[green]ok[/]" if p.consistent else "[red]outside[/]"
        t.add_row(p.name, display_unit(p.unit)[1], _fmt(p.predicted_sigma, p.unit),
                  _fmt(p.empirical_sigma, p.unit), f"{_fmt(lo, p.unit)}–{_fmt(hi, p.unit)}", ratio,
                  f"{_fmt(p.bias, p.unit)} ± {_fmt(p.bias_standard_error, p.unit)}", verdict)
    console.print(t)
    ok = "[green]consistent[/]" if res.nees_consistent else "[red]inconsistent[/]"
    what = "scored parameters" if res.null_space is None else "observable directions (the rank)"
    console.print(f"NEES: mean {res.nees_mean:.2f} over {n} trials, dof {res.dof} ({what}); "
                  f"{conf} % interval {res.nees_interval[0]:.2f}–{res.nees_interval[1]:.2f}: {ok}")
    if res.null_space is not None:
        ns = res.null_space
        console.print(f"Unobservable directions (null space of SΛS, {ns.nullity}), errors in targets: "
                      f"RMS {ns.null_rms:.3g} after calibrating, {ns.initial_null_rms:.3g} before, moved "
                      f"{ns.null_moved_rms:.2g}; the observable complement's whitened RMS error is "
                      f"{ns.observable_whitened_rms:.3f} (1 if the prediction holds)")
        for c in ns.coordinates:
            console.print("  " + ", ".join(f"{name} {w:+.2f}" for name, w in c))
    conv = "[green]" if res.failures == 0 else "[yellow]"
    console.print(f"Solver: {conv}{n - res.failures} of {n} trials converged[/] (non-converged ones are kept "
                  f"in the statistics); " + "; ".join(f"{k} ×{v}" for k, v in res.stop_reasons.items()))
    mc, (lo, hi) = res.model_check()
    fits = lo <= mc <= hi
    console.print(f"Model check: whitened cost 2·cost/dof = {mc:.4f} at the estimates, {conf} % interval "
                  f"{lo:.4f}–{hi:.4f} if the data has the noise the model assumes: "
                  + ("[green]consistent[/]" if fits else "[red]the data violates the model[/]")
                  + "; residual RMS per factor " + ", ".join(f"{k} {v:.2f}" for k, v in res.residual_rms().items()))
    if res.systematic is not None:
        top = sorted(res.systematic.items(), key=lambda kv: -abs(kv[1]))[:4]
        console.print("Physics the model lacks, alone (a noise-free trial calibrated from the truth), moves "
                      + ", ".join(f"{k} by {v:+.2f} σ" for k, v in top)
                      + ("" if abs(top[0][1]) < 0.5 else " [red](a bias the predicted σ does not include)[/]"))
    worst = res.worst_ratio()
    if worst is not None:
        console.print(f"Worst empirical σ / target: {worst[0]} {worst[1]:.3g}")


@app.command()
def validate(
    route: Annotated[Path, typer.Argument(help="Route file (any format `excite score` reads).")],
    runs: Annotated[int, typer.Option(help="Number of Monte Carlo trials.")] = 100,
    seed: Annotated[int, typer.Option(help="Seed; trial i uses default_rng([seed, i]).")] = 0,
    rig: Annotated[str, typer.Option(help="Bundled rig name or rig YAML path.")] = "robotaxi",
    times: Annotated[Optional[Path], typer.Option(help="KITTI times file.")] = None,
    duration: Annotated[Optional[float], typer.Option(help="Use only the first this many seconds [s].")] = None,
    imu_rate: Annotated[Optional[float], typer.Option(help="Override the rig's IMU rate [Hz] "
                                                          "(coarser: faster).")] = None,
    offset: Annotated[float, typer.Option(help="σ of the true calibration offsets, in targets.")] = 2.0,
    rank_rtol: Annotated[float, typer.Option(help="Solver: relative information below which a "
                                                   "direction is left where it started.")] = 1e-9,
    simulator: Annotated[str, typer.Option(help="'physical' (IMU integrated at 8× its rate, bias random "
                                                 "walk, wheel slip, tyre slip angle) or 'model' (data exactly as "
                                                 "the information model assumes).")] = "physical",
    log: Annotated[Optional[Path], typer.Option(help="Write the solver's log (one JSON object per step "
                                                     "of every trial) to this file.")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    quiet: Annotated[bool, typer.Option(help="No progress line.")] = False,
    driver: Annotated[bool, typer.Option("--driver", help="The route is a drivable plan (plan.json of excite "
                                                          "optimize --drivable): every trial drives it as another "
                                                          "person would (the driver model), and the prediction is "
                                                          "made from each trial's own drive.")] = False,
    scene: Annotated[Optional[str], typer.Option(help=seeing.HELP + " The simulator then ray-casts each lidar "
                                                 "frame pair's scans in it (--simulator model: the registration "
                                                 "error the scene's information predicts).")] = None,
) -> None:
    """Simulate the rig's sensors on the route, calibrate N times, compare with the predicted σ."""
    from ..rig.config import load_rig
    from ..io.routes import read_route
    from ..validate.calibrate import SolverSettings
    from ..validate.monte_carlo import MonteCarloSettings, Trial, monte_carlo
    from ..errors import ValidateError
    from ..validate.simulate import SimulationSettings

    r = load_rig(rig)
    if imu_rate is not None:
        r = with_imu_rate(r, imu_rate)
    world = seeing.load(scene)
    seeing.warn_blind(r, world)
    drives = None
    if driver and duration is not None:
        from ..errors import ValidateError

        raise ValidateError("--duration crops a route; a plan driven with --driver is driven whole")
    if driver or route.suffix.lower() == ".json":
        from ..motion.vehicle import drive
        from ..plan.drivable.plan import build, read_plan
        from ..plan.settings import vehicle_limits
        from ..plan.drivable.search import DrivableSettings

        limits = vehicle_limits(r, DrivableSettings().limits)
        built = build(read_plan(route), limits)
        traj = drive(built.timed().profile, r.suspension)
        if driver:
            import numpy as np

            from ..motion.driver import DriverModel, drive_course

            def drives(i: int):
                dc = drive_course(built.course, limits, DriverModel(), np.random.default_rng([seed, i]),
                                  duration_s=built.plan.duration_s)
                return seeing.seeing(drive(dc.profile, r.suspension), r, world)
    else:
        traj = read_route(route, times=times, suspension=r.suspension)
    if duration is not None:
        traj = crop(traj, duration)
    traj = seeing.seeing(traj, r, world)
    if simulator not in ("physical", "model"):
        raise ValidateError(f"--simulator must be 'physical' or 'model', got {simulator!r}")
    sim = SimulationSettings() if simulator == "physical" else SimulationSettings.model()
    settings = MonteCarloSettings(runs=runs, seed=seed, offset_in_targets=offset,
                                  simulation=sim, solver=SolverSettings(rank_rtol=rank_rtol))
    err = console(stderr=True)
    show = not quiet and not json_out and err.is_terminal

    def progress(trial: Trial) -> None:
        if show:
            err.print(f"trial {trial.index + 1}/{runs}: {trial.status} in {trial.iterations} iterations, "
                      f"{trial.seconds:.2f} s", end="\r")

    if drives is not None:
        from ..validate.monte_carlo import monte_carlo_driven

        res = monte_carlo_driven(drives, r, traj, settings, progress, scene=world)
    elif log is None:
        res = monte_carlo(traj, r, settings, progress, scene=world)
    else:
        try:
            fh = log.open("w")
        except OSError as e:
            raise ValidateError(f"--log: cannot write {log}: {e.strerror}") from None
        with fh:
            res = monte_carlo(traj, r, settings, progress, lambda rec: fh.write(json.dumps(rec) + "\n"), scene=world)
    if json_out:
        typer.echo(json.dumps(res.to_dict(), indent=2))
    else:
        if show:
            err.print(" " * 70, end="\r")
        if drives is not None:
            console().print(f"every trial drove the plan as another driver would (the driver model); the predicted σ "
                            f"is the RMS of each trial's own drive's σ, the NEES each trial's against its drive's "
                            f"information")
        print_result(res, console())
