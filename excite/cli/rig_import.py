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
