"""``excite rig from-…``: rig YAML from the files users have (the formats in
:mod:`excite.rig.importers`; a bag's ``/tf_static`` in :func:`excite.io.bags.rig_from_tf`), and ``excite rig
noise``: an odometry's drift densities from a drive with a reference."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer

from .score import rig_app

if TYPE_CHECKING:  # the importers need scipy and the bag reader: loaded by the commands only
    from ..rig.importers import ImportedRig


def _write(rig: "ImportedRig", output: Optional[Path]) -> None:
    """The rig YAML on stdout or in ``output``; what to review on stderr."""
    from ..rig import importers as rig_import

    text = rig_import.rig_yaml(rig)
    if output is None:
        typer.echo(text, nl=False)
    else:
        output.write_text(text, encoding="utf-8")
        typer.echo(f"wrote {output}", err=True)
    for note in rig.notes:
        if "re-orthonormalised" in note:
            typer.echo(f"note: {note}", err=True)
    lines = rig.review_lines()
    if lines:
        typer.echo(f"review before trusting a score ({len(lines)} key(s) marked REVIEW, not in the source):", err=True)
        for line in lines:
            typer.echo(f"  {line}", err=True)


Output = Annotated[Optional[Path], typer.Option("--output", "-o", help="Write the rig YAML here (default: stdout).")]
Name = Annotated[Optional[str], typer.Option(help="Rig name (default: the file's name).")]
Imu = Annotated[Optional[str], typer.Option(help="IMU frame: the body frame B.")]
Base = Annotated[Optional[str], typer.Option(help="Base frame: the vehicle frame V (default: base_link, else the "
                                                  "tree's root).")]
Lidar = Annotated[Optional[list[str]], typer.Option("--lidar", help="Frame of a lidar (repeatable).")]
Camera = Annotated[Optional[list[str]], typer.Option("--camera", help="Frame of a camera (repeatable).")]
Gnss = Annotated[Optional[list[str]], typer.Option(
    "--gnss", help="Frame of a GNSS antenna (repeatable; default: every frame named like one, gnss/gps).")]
NoGnss = Annotated[bool, typer.Option("--no-gnss", help="Place no GNSS antenna.")]


def _antennas(gnss: Optional[list[str]], no_gnss: bool) -> Optional[list[str]]:
    return [] if no_gnss else (gnss or None)


@rig_app.command("from-tf")
def from_tf(
    bag: Annotated[Path, typer.Argument(help="Bag with a /tf_static tree (.bag, .mcap, ROS 2 folder).")],
    imu: Annotated[str, typer.Option(help="IMU frame: the body frame B.")],
    base: Annotated[str, typer.Option(help="Base frame: the vehicle frame V (e.g. base_link).")],
    lidar: Lidar = None,
    camera: Camera = None,
    gnss: Gnss = None,
    no_gnss: NoGnss = False,
    name: Name = None,
    output: Output = None,
) -> None:
    """A rig YAML from a bag's /tf_static: T_V_B and every sensor's T_B_S composed over the tree."""
    from ..io.bags import rig_from_tf

    _write(rig_from_tf(bag, imu=imu, base=base, lidar=lidar or [], camera=camera or [],
                       gnss=_antennas(gnss, no_gnss), name=name), output)


@rig_app.command("from-kalibr")
def from_kalibr(
    camchain: Annotated[Path, typer.Argument(help="Kalibr camchain (camN.T_cam_imu, or OpenVINS's T_imu_cam).")],
    imu_yaml: Annotated[Optional[Path], typer.Argument(
        help="Kalibr IMU file: its input imu.yaml or its output imu-*.yaml (imu0:, …).")] = None,
    imu: Annotated[Optional[str], typer.Option(
        "--imu", help="The IMU of an output file with several (default: imu0, the camchain's).")] = None,
    camera_rate: Annotated[Optional[float], typer.Option(help="Camera frame rate [Hz].")] = None,
    name: Name = None,
    output: Output = None,
) -> None:
    """A rig YAML from a Kalibr camera-IMU calibration (as Kalibr and OpenVINS write it)."""
    from ..rig.importers import rig_from_kalibr

    _write(rig_from_kalibr(camchain, imu_yaml, name=name, camera_rate_hz=camera_rate, imu=imu), output)


@rig_app.command("from-vins")
def from_vins(
    config: Annotated[Path, typer.Argument(help="VINS-Fusion configuration (body_T_cam0: !!opencv-matrix).")],
    name: Name = None,
    output: Output = None,
) -> None:
    """A rig YAML from a VINS-Fusion configuration."""
    from ..rig.importers import rig_from_vins

    _write(rig_from_vins(config, name=name), output)


@rig_app.command("from-lio-sam")
def from_lio_sam(
    params: Annotated[Path, typer.Argument(help="LIO-SAM params.yaml (extrinsicTrans, extrinsicRot).")],
    name: Name = None,
    output: Output = None,
) -> None:
    """A rig YAML from LIO-SAM's params.yaml."""
    from ..rig.importers import rig_from_lio_sam

    _write(rig_from_lio_sam(params, name=name), output)


@rig_app.command("from-fast-lio")
def from_fast_lio(
    config: Annotated[Path, typer.Argument(help="FAST-LIO or FAST-LIVO configuration (extrinsic_T, extrinsic_R).")],
    name: Name = None,
    output: Output = None,
) -> None:
    """A rig YAML from a FAST-LIO (or FAST-LIVO) configuration."""
    from ..rig.importers import rig_from_fast_lio

    _write(rig_from_fast_lio(config, name=name), output)


@rig_app.command("from-urdf")
def from_urdf(
    urdf: Annotated[Path, typer.Argument(help="URDF (a xacro needs expanding first: xacro FILE > robot.urdf).")],
    imu: Annotated[Optional[str], typer.Option(help="IMU link: the body frame B (default: the Gazebo imu sensor's).")] = None,
    base: Base = None,
    lidar: Lidar = None,
    camera: Camera = None,
    gnss: Gnss = None,
    no_gnss: NoGnss = False,
    name: Name = None,
    output: Output = None,
) -> None:
    """A rig YAML from a URDF: sensor links placed through the joints."""
    from ..rig.importers import rig_from_urdf

    _write(rig_from_urdf(urdf, imu=imu, base=base, lidar=lidar, camera=camera, gnss=_antennas(gnss, no_gnss),
                         name=name), output)


@rig_app.command("from-autoware")
def from_autoware(
    sensor_kit: Annotated[Path, typer.Argument(help="Autoware sensor_kit_calibration.yaml.")],
    sensors_calibration: Annotated[Optional[Path], typer.Argument(
        help="Autoware sensors_calibration.yaml (places the sensor kit on base_link).")] = None,
    imu: Imu = None,
    base: Base = None,
    lidar: Lidar = None,
    camera: Camera = None,
    gnss: Gnss = None,
    no_gnss: NoGnss = False,
    name: Name = None,
    output: Output = None,
) -> None:
    """A rig YAML from Autoware's sensor-kit calibration files: every sensor frame placed by its name
    (velodyne_*, livox_* lidars, camera* cameras, gnss*, the *imu* frame as B) unless named."""
    from ..rig.importers import rig_from_autoware

    _write(rig_from_autoware(sensor_kit, sensors_calibration=sensors_calibration, imu=imu, base=base, lidar=lidar,
                             camera=camera, gnss=_antennas(gnss, no_gnss), name=name), output)


@rig_app.command("noise")
def noise(
    odometry: Annotated[Path, typer.Argument(help="The odometry's poses: a bag (with --topic), a TUM file or an "
                                                  "EuRoC CSV.")],
    reference: Annotated[Optional[Path], typer.Option(
        help="The reference of the same drive (ground truth, a GNSS/INS pose): a bag (with --reference-topic), "
             "a TUM file or an EuRoC CSV (default: the odometry's bag).")] = None,
    topic: Annotated[Optional[str], typer.Option(help="Bags: the odometry's pose topic.")] = None,
    reference_topic: Annotated[Optional[str], typer.Option(help="Bags: the reference's pose topic.")] = None,
    max_time_offset: Annotated[float, typer.Option(
        help="Search the clocks' offset within ± this [s].")] = 1.0,
    time_offset: Annotated[Optional[float], typer.Option(
        help="The clocks' offset [s] (the reference at t + offset is the odometry at t), instead of searching.")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the estimate as JSON.")] = False,
) -> None:
    """An odometry's drift densities (the noise of a rig's lidar or camera) from a drive logged with a
    reference: the densities with their uncertainty, and the rig lines to paste."""
    import json

    from ..io.timed_poses import read_timed_poses
    from ..rig.noise import estimate_drift

    if reference is None and reference_topic is None:
        if topic is None:
            raise typer.BadParameter("name the reference: --reference FILE, or --reference-topic in the odometry's "
                                     "bag (or --topic alone: the densities the odometry's covariance reports)",
                                     param_hint="--reference")
        _reported(odometry, topic, json_out)
        return
    odom = read_timed_poses(odometry, topic)
    ref = read_timed_poses(reference or odometry, reference_topic)
    est = estimate_drift(odom, ref, max_time_offset_s=max_time_offset, time_offset_s=time_offset)
    if json_out:
        typer.echo(json.dumps(est.to_dict(), indent=2))
        return
    from .app import console

    _print_drift(est, console(), f"{topic or odometry.name} against {reference_topic or (reference or odometry).name}")


def _print_drift(est, con, title: str) -> None:
    from rich.table import Table

    con.print(f"[bold]{title}[/]: {est.pairs} frame pairs over {est.duration_s:.0f} s ({est.rate_hz:.1f} Hz)")
    t = Table(title="Drift densities (σ of a relative pose over Δt = density·√Δt, per axis)", title_justify="left")
    for col, right in (("", False), ("between frames", True), ("± (1σ)", True), ("per axis x, y, z", True),
                       ("over 1 s", True), ("over 10 s", True), ("white, per pose", True)):
        t.add_column(col, justify="right" if right else "left")
    for what, d, white_unit in (("rotation [deg/√s]", est.rotation, "deg"),
                                ("translation [m/√s]", est.translation, "m")):
        t.add_row(what, f"{d.value:.4g}", f"{d.sigma:.2g}", ", ".join(f"{x:.3g}" for x in d.per_axis),
                  f"{d.over_1s:.3g}", f"{d.over_10s:.3g}", f"{d.white_sigma:.2g} {white_unit}")
    con.print(t)
    con.print(f"alignment: time offset {est.time_offset_s * 1e3:+.1f} ms (the reference at t + offset is the "
              f"odometry at t), frames {est.frame_rotation_deg:.2f}° apart, lever arm "
              f"({', '.join(f'{x:.3f}' for x in est.lever_arm_m)}) m, scale {est.scale:.4f} (metres per odometry unit)")
    for note in est.notes:
        con.print(f"note: {note}")
    con.print("rig lines to paste under the lidar's or camera's entry:")
    con.print(est.rig_lines().rstrip(), highlight=False, markup=False)


def _reported(bag: Path, topic: str, json_out: bool) -> None:
    """The densities an odometry topic's own covariance reports (no reference to check them)."""
    import json

    from ..io.bags import odometry_log, read_pose_covariances
    from ..rig.noise import reported_densities

    cov = read_pose_covariances(bag, topic)
    rep = reported_densities(odometry_log(cov, int(cov.t_ns.min()), bag, topic).covariance)
    if json_out:
        typer.echo(json.dumps({"rotation_density_deg_per_sqrt_s": rep.rotation_deg_per_sqrt_s,
                               "translation_density_m_per_sqrt_s": rep.translation_m_per_sqrt_s,
                               "messages": rep.messages}, indent=2))
        return
    r, t = rep.rotation_deg_per_sqrt_s, rep.translation_m_per_sqrt_s
    typer.echo(f"{topic}: the densities its own covariance reports ({rep.messages} messages; not checked "
               "against a reference):")
    typer.echo(f"  rotation {r[1]:.3g} deg/√s (10–90 % of the messages: {r[0]:.3g}–{r[2]:.3g})")
    typer.echo(f"  translation {t[1]:.3g} m/√s (10–90 %: {t[0]:.3g}–{t[2]:.3g})")
    typer.echo("rig lines to paste under the lidar's or camera's entry (or set noise.use_reported_covariance: "
               "true to weigh each frame pair by its message):")
    typer.echo(rep.rig_lines().rstrip())
