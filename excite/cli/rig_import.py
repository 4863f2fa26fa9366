"""``excite rig from-tf | from-kalibr | from-autoware``: rig YAML from the files users have
(logic in :mod:`excite.rig.importers`)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Optional

import typer

from .score import rig_app

if TYPE_CHECKING:  # the importers need scipy and the bag reader: loaded by the commands only
    from ..rig.importers import ImportedRig


def _write(rig: "ImportedRig", output: Optional[Path]) -> None:
    from ..rig import importers as rig_import

    text = rig_import.rig_yaml(rig)
    if output is None:
        typer.echo(text, nl=False)
        return
    output.write_text(text, encoding="utf-8")
    n = text.count("DEFAULT: review")
    typer.echo(f"wrote {output} ({n} defaulted key(s) marked 'DEFAULT: review')", err=True)


Output = Annotated[Optional[Path], typer.Option("--output", "-o", help="Write the rig YAML here (default: stdout).")]
Lidar = Annotated[list[str], typer.Option("--lidar", help="Frame of a lidar (repeatable).")]
Camera = Annotated[list[str], typer.Option("--camera", help="Frame of a camera (repeatable).")]
Gnss = Annotated[Optional[list[str]], typer.Option(
    "--gnss", help="Frame of a GNSS antenna (repeatable; default: every frame named like one, gnss/gps).")]
NoGnss = Annotated[bool, typer.Option("--no-gnss", help="Place no GNSS antenna.")]


@rig_app.command("from-tf")
def from_tf(
    bag: Annotated[Path, typer.Argument(help="Bag with a /tf_static tree (.bag, .mcap, ROS 2 folder).")],
    imu: Annotated[str, typer.Option(help="IMU frame: the body frame B.")],
    base: Annotated[str, typer.Option(help="Base frame: the vehicle frame V (e.g. base_link).")],
    lidar: Lidar = [],
    camera: Camera = [],
    gnss: Gnss = None,
    no_gnss: NoGnss = False,
    name: Annotated[Optional[str], typer.Option(help="Rig name (default: the bag's name).")] = None,
    output: Output = None,
) -> None:
    """A rig YAML from a bag's /tf_static: T_V_B and every sensor's T_B_S composed over the tree."""
    from ..io.bags import rig_from_tf

    _write(rig_from_tf(bag, imu=imu, base=base, lidar=lidar, camera=camera,
                       gnss=[] if no_gnss else (gnss or None), name=name), output)


@rig_app.command("from-kalibr")
def from_kalibr(
    camchain: Annotated[Path, typer.Argument(help="Kalibr camchain-imucam YAML (camN.T_cam_imu).")],
    imu_yaml: Annotated[Path, typer.Argument(help="Kalibr imu.yaml (noise densities, update_rate).")],
    camera_rate: Annotated[Optional[float], typer.Option(help="Camera frame rate [Hz].")] = None,
    name: Annotated[Optional[str], typer.Option(help="Rig name.")] = None,
    output: Output = None,
) -> None:
    """A rig YAML from a Kalibr camera-IMU calibration."""
    from ..rig import importers as rig_import

    _write(rig_import.rig_from_kalibr(camchain, imu_yaml, name=name, camera_rate_hz=camera_rate), output)


@rig_app.command("from-autoware")
def from_autoware(
    sensor_kit: Annotated[Path, typer.Argument(help="Autoware sensor_kit_calibration.yaml.")],
    imu: Annotated[str, typer.Option(help="IMU frame: the body frame B.")],
    base: Annotated[str, typer.Option(help="Base frame: the vehicle frame V.")],
    lidar: Lidar = [],
    camera: Camera = [],
    sensors_calibration: Annotated[Optional[Path], typer.Option(
        help="Autoware sensors_calibration.yaml (places the sensor kit on base_link).")] = None,
    gnss: Gnss = None,
    no_gnss: NoGnss = False,
    name: Annotated[Optional[str], typer.Option(help="Rig name.")] = None,
    output: Output = None,
) -> None:
    """A rig YAML from Autoware sensor-kit calibration files."""
    from ..rig import importers as rig_import

    _write(rig_import.rig_from_autoware(sensor_kit, imu=imu, base=base, lidar=lidar, camera=camera,
                                        sensors_calibration=sensors_calibration,
                                        gnss=[] if no_gnss else (gnss or None), name=name), output)
