"""``excite score`` and ``excite rig``: the evaluator's report of a route; the bundled rigs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Optional

import typer

from ..core import bounds
from . import seeing
from .app import app, console, imports

if TYPE_CHECKING:
    from ..score.evaluate import Report

def print_report(rep: Report, console: Any, rig: Any = None) -> None:
    """The report as tables for a terminal; with the ``rig``, the frame its ``trans_*`` are in."""
    from rich.table import Table

    from ..core.units import human

    verdict = "[green]PASS[/]" if rep.passed else "[red]FAIL[/]"
    from rich.markup import escape

    where = seeing.line(rep.scene)
    console.print(f"[bold]{rep.route}[/] with rig [bold]{rep.rig}[/]" + (f" in {escape(where)}" if where else "")
                  + f": {rep.duration_s:.1f} s, {rep.length_m:.0f} m, {rep.n_keyframes} keyframes")
    cond = "∞" if rep.condition_number is None else f"{rep.condition_number:.3g}"
    console.print(f"score λ_min(SΛS) = [bold]{rep.score:.4g}[/]  {verdict}   rank {rep.rank}/"
                  f"{rep.rank + rep.nullity} (normalised threshold {rep.rank_threshold:.2g})   condition {cond}")
    t = Table(title="Cramér–Rao σ per parameter (from the drive alone)", title_justify="left")
    t.add_column("parameter")
    t.add_column("σ", justify="right")
    t.add_column("target", justify="right")
    t.add_column("σ/target", justify="right")
    t.add_column("")
    show_prior = any(p.sigma_with_prior is not None for p in rep.parameters)
    if show_prior:
        t.add_column("σ with priors", justify="right")
    for p in rep.parameters:
        ratio = "—" if p.sigma is None else f"{p.sigma / p.target:.2f}"
        row = [p.name, human(p.sigma, p.unit), human(p.target, p.unit), ratio,
               "[green]ok[/]" if p.ok else "[red]✗[/]"]
        if show_prior:
            row.append(human(p.sigma_with_prior, p.unit) if p.sigma_with_prior is not None else "")
        t.add_row(*row)
    console.print(t)
    if rig is not None and any(c.quantity == "trans" for c in rig.scored):
        from ..rig.config import body_axes

        console.print(f"trans_* are positions in the IMU frame B, whose axes point "
                      f"{body_axes(rig.config.vehicle.T_V_B.R)} of the vehicle (T_V_B); rot_* are rotations "
                      "about each sensor's own axes")
    if rep.weak_modes:
        m = Table(title="Weakest directions (eigenvectors of SΛS, ascending)", title_justify="left")
        m.add_column("λ", justify="right")
        m.add_column("σ/target", justify="right")
        m.add_column("dominant coordinates")
        m.add_column("what it takes", overflow="fold")
        for mode in rep.weak_modes:
            coords = ", ".join(f"{n} {w:+.2f}" for n, w in mode.coordinates)
            s = "∞" if mode.sigma_in_targets is None else f"{mode.sigma_in_targets:.3g}"
            m.add_row(f"{mode.eigenvalue_scaled:.3g}", s, coords, mode.advice)
        console.print(m)
    if rep.segments:
        s = Table(title="Information per route segment (segment alone)", title_justify="left")
        s.add_column("from [s]", justify="right")
        s.add_column("to [s]", justify="right")
        s.add_column("score", justify="right")
        s.add_column("along weakest mode", justify="right")
        for seg in rep.segments:
            s.add_row(f"{seg.t_start_s:.1f}", f"{seg.t_end_s:.1f}", f"{seg.score:.3g}",
                      f"{seg.weakest_mode_information:.3g}")
        console.print(s)


@app.command(epilog=f"Bounds (excite.core.bounds): {bounds.describe()}.")
def score(
    route: Annotated[Path, typer.Argument(help="Route file: waypoints/control CSV, GeoJSON, TUM, "
                                                "KITTI (with --times), EuRoC CSV, or a bag (.bag, "
                                                ".mcap, ROS 2 folder) with --topic.")],
    times: Annotated[Optional[Path], typer.Option(help="KITTI times file.")] = None,
    rig: Annotated[str, typer.Option(help="Bundled rig name or rig YAML path.")] = "robotaxi",
    json_out: Annotated[bool, typer.Option("--json", help="Print the JSON report.")] = False,
    export: Annotated[Optional[Path], typer.Option(help="Write J, H, Λ and the column map to .npz.")] = None,
    segments: Annotated[int, typer.Option(help="Report the information of this many route segments.")] = 0,
    plot: Annotated[Optional[Path], typer.Option(help="Write a PNG: the route coloured by information, "
                                                      "the scaled spectrum, σ/target per parameter.")] = None,
    plot_parameter: Annotated[Optional[str], typer.Option(
        help="Colour the route by the information on this parameter (default: the weakest mode).")] = None,
    topic: Annotated[Optional[str], typer.Option(
        help="Bags: the trajectory source, a pose topic or a TF chain /tf:PARENT.CHILD.")] = None,
    imu_topic: Annotated[Optional[str], typer.Option(
        help="Bags: a sensor_msgs/Imu topic; its measured rate and specific force replace the "
             "poses' derivatives.")] = None,
    start: Annotated[Optional[float], typer.Option(help="Bags: window start [s from the bag's start].")] = None,
    end: Annotated[Optional[float], typer.Option(help="Bags: window end [s from the bag's start].")] = None,
    vehicle_frame: Annotated[Optional[str], typer.Option(
        help="Bags: the robot frame to take as V, reached from the poses' frame via /tf_static.")] = None,
    axes: Annotated[str, typer.Option(
        help="Bags: axes of the logged poses: vehicle (x forward, z up) or optical (x right, "
             "y down, z forward).")] = "vehicle",
    gnss_topic: Annotated[Optional[str], typer.Option(
        help="Bags: a sensor_msgs/NavSatFix topic: the rig's GNSS antenna is scored with the fixes "
             "it holds (outages, and the reported covariance where the rig asks for it).")] = None,
    odometry_topic: Annotated[Optional[str], typer.Option(
        help="Bags: a nav_msgs/Odometry or PoseWithCovarianceStamped topic whose pose covariance "
             "weighs the frame pairs of the rig's lidar or camera that sets "
             "noise.use_reported_covariance (each message's: its increment since the last).")] = None,
    scene: Annotated[Optional[str], typer.Option(help=seeing.HELP)] = None,
) -> None:
    """How well does this drive determine every calibration parameter of the rig?"""
    with imports():
        from ..score.evaluate import Options, evaluate, max_segments
        from ..rig.config import load_rig
        from ..io.routes import read_route

    if plot is not None and plot.suffix.lower() != ".png":
        raise typer.BadParameter(f"writes a PNG: name the file .png, got {plot.name!r}", param_hint="--plot")
    r = load_rig(rig)
    if plot_parameter is not None and plot_parameter not in [c.name for c in r.scored]:
        raise typer.BadParameter(f"no parameter {plot_parameter!r} in rig {r.name} "
                                 f"(parameters: {', '.join(c.name for c in r.scored)})",
                                 param_hint="--plot-parameter")
    bag = None
    if any(x is not None for x in (topic, imu_topic, start, end, vehicle_frame, gnss_topic,
                                   odometry_topic)) or axes != "vehicle":
        from ..io.bags import BagSource

        antennas = [s.name for s in r.config.sensors if s.kind == "gnss"]
        if gnss_topic is not None and len(antennas) != 1:
            raise typer.BadParameter(f"rig {r.name} has {len(antennas)} GNSS antennas: --gnss-topic needs "
                                     "exactly one", param_hint="--gnss-topic")
        reported = [s.name for s in r.config.sensors if s.kind in ("lidar", "camera")
                    and s.noise.use_reported_covariance]
        if odometry_topic is not None and len(reported) != 1:
            raise typer.BadParameter(f"rig {r.name} has {len(reported)} lidars or cameras with "
                                     "noise.use_reported_covariance: --odometry-topic needs exactly one",
                                     param_hint="--odometry-topic")
        bag = BagSource(topic, imu_topic, start, end, vehicle_frame, axes, gnss_topic,
                        antennas[0] if antennas else "gnss", odometry_topic,
                        reported[0] if reported else "lidar")
    world = seeing.load(scene)
    seeing.warn_blind(r, world)
    traj = seeing.seeing(read_route(route, times=times, suspension=r.suspension, bag=bag), r, world)
    for s in r.config.sensors:
        if s.kind in ("lidar", "camera") and s.noise.use_reported_covariance and s.name not in traj.logs:
            typer.secho(f"warning: {s.name} sets noise.use_reported_covariance and the drive carries no covariance "
                        "of its odometry (--odometry-topic): its densities hold", err=True, fg="yellow")
    if bag is not None:  # a bag was read (with --imu-topic: its measured IMU too)
        from ..io.bags import ImuTrajectory, imu_agreement

        if isinstance(traj, ImuTrajectory):
            pose = r.config.vehicle.T_V_B
            typer.echo(f"IMU {imu_topic} (frame {traj.imu_frame}) gives the angular rate and specific "
                       f"force; {imu_agreement(traj, pose.R, pose.p).text()}", err=True)
        if gnss_topic is not None:
            t = traj.logs[bag.gnss_sensor].t
            gap = max((b - a for a, b in zip(t[:-1], t[1:])), default=0.0)
            typer.echo(f"GNSS {gnss_topic}: {t.size} fixes over {t[-1] - t[0]:.1f} s for {bag.gnss_sensor} "
                       f"(longest gap {gap:.2f} s)", err=True)
        if odometry_topic is not None:
            import numpy as np

            log = traj.logs[bag.odometry_sensor]
            n = int(np.all(np.isfinite(log.covariance), axis=(1, 2)).sum())
            typer.echo(f"odometry {odometry_topic}: {log.t.size} messages, {n} with a pose covariance, weigh "
                       f"the frame pairs of {bag.odometry_sensor}", err=True)
    rep = evaluate(traj, r, Options(segments=segments))
    for w in rep.warnings:  # on stderr: the report (or its JSON) stays what stdout carries
        typer.secho(f"warning: {w}", err=True, fg="yellow")
    if plot is not None:
        from ..score import plots

        # the route panel needs segments; they are printed only when asked for
        with_segments = rep if segments else evaluate(traj, r, Options(
            segments=min(plots.segment_count(traj.duration), max_segments([traj], r))))
        plot.write_bytes(plots.report_figure(with_segments, traj, plot_parameter))
    if export is not None:
        rep.export_npz(export)
    if json_out:
        typer.echo(json.dumps(rep.to_dict(), indent=2))
    else:
        print_report(rep, console(), r)


rig_app = typer.Typer(no_args_is_help=True, help="Show the bundled rigs; import rigs from Kalibr, OpenVINS, "
                                                 "VINS-Fusion, LIO-SAM, FAST-LIO, URDF, Autoware and TF "
                                                 "files; measure an odometry's noise densities.")
app.add_typer(rig_app, name="rig")


@rig_app.command("show")
def rig_show(name: Annotated[str, typer.Argument(help="Bundled rig name or rig YAML path.")] = "robotaxi") -> None:
    """Print a rig's YAML (validated first)."""
    from ..rig.config import load_rig, rig_text

    load_rig(name)
    typer.echo(rig_text(name), nl=False)


@rig_app.command("list")
def rig_list() -> None:
    """Names of the bundled rigs."""
    from ..rig.config import bundled_rigs

    for n in bundled_rigs():
        typer.echo(n)
