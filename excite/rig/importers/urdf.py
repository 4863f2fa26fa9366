"""A URDF: the sensor frames are links, placed through the joints between them.

Each ``<joint>`` gives its child link's pose in its parent link, ``<origin xyz rpy>`` (metres;
roll, pitch, yaw in radians about fixed axes: ``R = Rz(yaw)·Ry(pitch)·Rx(roll)``). A movable
joint (revolute, continuous, prismatic) is taken at its zero position, and noted. The IMU, base,
lidar and camera links are named by the user as with TF; without lidars and cameras named, the
sensors come from Gazebo's ``<gazebo reference="LINK"><sensor type=…>`` elements where the file
has them (``ray``/``gpu_ray``/``gpu_lidar`` lidars, ``camera``/``depth``/``rgbd_camera`` cameras,
``gps``/``navsat`` antennas, ``imu`` the body frame), with their ``update_rate``.

A xacro (``.xacro``, or ``xacro:`` elements) is a program that writes a URDF: expand it first.
The file is parsed with defusedxml (no DTD, no entities) and its elements are counted as they
are read: at most 2 × :data:`~.common.MAX_FRAMES` links and joints.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from defusedxml import DefusedXmlException
from defusedxml.ElementTree import ParseError, iterparse
from scipy.spatial.transform import Rotation

from ...errors import RigError
from . import common
from .tree import Hop, Tree, rig_from_tree

XACRO_NS = "http://www.ros.org/wiki/xacro"
GAZEBO_KINDS = {"ray": "lidar", "gpu_ray": "lidar", "lidar": "lidar", "gpu_lidar": "lidar",
                "camera": "camera", "depth": "camera", "multicamera": "camera", "rgbd_camera": "camera",
                "gps": "gnss", "navsat": "gnss", "imu": "imu"}


def _floats(text: str | None, path: Path, key: str) -> np.ndarray:
    if text is None:
        return np.zeros(3)
    try:
        v = np.array([float(x) for x in text.split()])
    except ValueError:
        raise RigError(f"{path}: {key}: expected three numbers, got {text!r}") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise RigError(f"{path}: {key}: expected three finite numbers, got {text!r}")
    return v


def xacro_hint(path: Path) -> str:
    return (f"{path}: a xacro file (a program that writes a URDF): expand it first, `xacro {path.name} > "
            f"{path.name.removesuffix('.xacro').removesuffix('.urdf')}.urdf` (ROS 2: `ros2 run xacro xacro …`), "
            "and import the URDF")


def read_urdf(path: str | Path) -> tuple[Tree, list[str], dict[str, tuple[str, float | None]]]:
    """The tree of a URDF's joints, notes, and Gazebo's sensors (link → (kind, rate))."""
    path = Path(path)
    if path.suffix == ".xacro":
        raise RigError(xacro_hint(path))
    common.read_text(path, "a URDF")  # the size bound, before the parser starts
    hops, notes, sensors = [], [], {}
    count, robot = 0, None
    try:
        for event, el in iterparse(str(path), events=("start", "end"), forbid_dtd=True):
            if event == "start":
                count += el.tag in ("link", "joint")
                if count > 2 * common.MAX_FRAMES:
                    raise RigError(f"{path}: more than {common.MAX_FRAMES} links or joints, over the limit of a "
                                   "rig's tree")
                if robot is None:
                    robot = el.tag
                    if robot != "robot":
                        raise RigError(f"{path}: the root element is <{robot}>, not a URDF's <robot>")
                if el.tag.startswith(f"{{{XACRO_NS}}}"):
                    raise RigError(xacro_hint(path))
                continue
            if el.tag == "joint":
                name = el.get("name", "?")
                parent, child = el.find("parent"), el.find("child")
                if parent is None or child is None or not parent.get("link") or not child.get("link"):
                    raise RigError(f"{path}: joint {name!r}: needs <parent link=…> and <child link=…>")
                origin = el.find("origin")
                xyz = _floats(None if origin is None else origin.get("xyz"), path, f"joint {name!r} origin xyz")
                rpy = _floats(None if origin is None else origin.get("rpy"), path, f"joint {name!r} origin rpy")
                kind = el.get("type", "fixed")
                if kind != "fixed":
                    notes.append(f"joint {name} is {kind}: taken at its zero position")
                R = Rotation.from_euler("xyz", rpy).as_matrix()  # fixed axes: Rz(y)·Ry(p)·Rx(r)
                hops.append(Hop(parent.get("link"), child.get("link"), R, xyz))
                el.clear()
            elif el.tag == "gazebo" and el.get("reference"):
                s = el.find("sensor")
                if s is not None and s.get("type") in GAZEBO_KINDS:
                    rate = s.findtext("update_rate")
                    try:
                        hz = float(rate) if rate is not None else None
                    except ValueError:
                        hz = None
                    sensors[el.get("reference")] = (GAZEBO_KINDS[s.get("type")], hz if hz and hz > 0 else None)
                el.clear()
    except (ParseError, DefusedXmlException) as exc:
        raise RigError(f"{path}: not a URDF ({exc})") from None
    if not hops:
        raise RigError(f"{path}: no <joint>: a URDF's sensor frames are placed by joints")
    return Tree(hops, path, "joint"), notes, sensors


def rig_from_urdf(path: str | Path, *, imu: str | None = None, base: str | None = None,
                  lidar: list[str] | None = None, camera: list[str] | None = None,
                  gnss: list[str] | None = None, name: str | None = None) -> common.ImportedRig:
    """A rig from a URDF (see the module notes)."""
    path = Path(path)
    tree, notes, gazebo = read_urdf(path)
    by_kind = {k: sorted(link for link, (kind, _) in gazebo.items() if kind == k) for k in ("lidar", "camera", "gnss", "imu")}
    if imu is None:
        if len(by_kind["imu"]) != 1:
            raise RigError(f"{path}: name the IMU link with --imu (Gazebo sensors of type imu: "
                           f"{', '.join(by_kind['imu']) or 'none'})")
        imu = by_kind["imu"][0]
    if base is None:
        roots = sorted(f for f in tree.frames if f not in tree.parent)
        base = "base_link" if "base_link" in tree.frames else roots[0]
    if lidar is None and camera is None:
        lidar, camera = by_kind["lidar"], by_kind["camera"]
        gnss = by_kind["gnss"] if gnss is None else gnss
        if gazebo:
            notes.append("sensors from the file's Gazebo <sensor> elements")
    rates = {link: hz for link, (_, hz) in gazebo.items() if hz is not None}
    return rig_from_tree(tree, imu=imu, base=base, lidar=list(lidar or []), camera=list(camera or []), gnss=gnss,
                         name=name or common.rig_name(path), notes=[f"from the URDF {path.name}"] + notes,
                         rates=rates)
