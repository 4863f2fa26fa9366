"""A rig from a bag's ``/tf_static`` tree (:func:`rig_from_tf`): the bag is read here, the tree
composed by :mod:`excite.rig.importers.tree` (B is the IMU frame, ``T_V_B`` the IMU in the base
frame, each sensor's ``T_B_S`` its frame in the IMU frame, over every hop). A frame named like a
GNSS antenna (``gnss``, ``gps``, ``gnss_link``, ``gps/antenna`` …) becomes a ``kind: gnss`` sensor
at its position, unless the antennas are named (``gnss=[…]``, ``[]`` for none)."""

from __future__ import annotations

from pathlib import Path

from scipy.spatial.transform import Rotation

from ..rig.importers import ImportedRig, common
from ..rig.importers.tree import Hop, Tree, rig_from_tree
from .bags import read_static_tf


def rig_from_tf(path: str | Path, *, imu: str, base: str, lidar: list[str] = (), camera: list[str] = (),
                gnss: list[str] | None = None, name: str | None = None) -> ImportedRig:
    """A rig from a bag's ``/tf_static``: B is the ``imu`` frame, V the ``base`` frame; sensors at
    the ``lidar`` and ``camera`` frames, named after them; GNSS antennas at ``gnss`` (default:
    every frame named like one)."""
    path = Path(path)
    static = read_static_tf(path)
    tree = Tree([Hop(parent, child, Rotation.from_quat(q).as_matrix(), p) for child, (parent, p, q) in static.items()],
                f"{path} /tf_static")
    return rig_from_tree(tree, imu=imu, base=base, lidar=list(lidar), camera=list(camera),
                         gnss=None if gnss is None else list(gnss), name=name or common.rig_name(path),
                         notes=[f"from the /tf_static tree of {path.name}"])
