"""A tree of frames (TF's ``/tf_static``, Autoware's calibration files, a URDF's joints) and the
rig it makes: the IMU frame is the body frame B, ``T_V_B`` the IMU in the base frame V, and each
sensor's ``T_B_S`` its frame in the IMU frame, composed over every hop between them.

The tree is checked as it is built: at most :data:`~.common.MAX_FRAMES` frames, each frame with
one parent, no cycle; a frame that is asked for and missing, or two frames that no hop links,
is named. Poses compose in time linear in the frames.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from ...errors import RigError
from . import common

# frame names → kinds, for sources whose every frame is a sensor (Autoware's calibration files)
LIDAR = re.compile(r"velodyne|livox|lidar|ouster|hesai|pandar|robosense|rslidar|laser|vlp|innovusion|luminar|aeva",
                   re.IGNORECASE)
CAMERA = re.compile(r"camera|(^|[/_])cam\d*([/_]|$)", re.IGNORECASE)
IMU = re.compile(r"(^|[/_])imu([/_]|$)", re.IGNORECASE)
GNSS = re.compile(r"(^|[/_])(gnss|gps)([/_]|$)", re.IGNORECASE)


@dataclass(frozen=True)
class Hop:
    """The pose of ``child`` in ``parent``."""

    parent: str
    child: str
    R: np.ndarray
    p: np.ndarray


class Tree:
    """Frames linked by hops; ``source`` names the file in every error, ``hop`` what a hop is
    called there (a joint, a transform)."""

    def __init__(self, hops: Iterable[Hop], source: str | Path, hop: str = "transform"):
        self.source = str(source)
        self.parent: dict[str, Hop] = {}
        for h in hops:
            if h.child in self.parent and self.parent[h.child].parent != h.parent:
                raise RigError(f"{self.source}: frame {h.child!r} has two parents, {self.parent[h.child].parent!r} "
                               f"and {h.parent!r}: a tree has one")
            self.parent[h.child] = h
            if len(self.parent) > common.MAX_FRAMES:
                raise RigError(f"{self.source}: more than {common.MAX_FRAMES} frames, over the limit of a rig's tree")
        self.hop = hop
        self._check_cycles()
        self._root: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}

    @property
    def frames(self) -> set[str]:
        return set(self.parent) | {h.parent for h in self.parent.values()}

    def leaves(self) -> list[str]:
        parents = {h.parent for h in self.parent.values()}
        return sorted(f for f in self.parent if f not in parents)

    def _check_cycles(self) -> None:
        state: dict[str, int] = {}  # 1: on the current walk, 2: reaches a root
        for start in self.parent:
            walk, f = [], start
            while f in self.parent and state.get(f) != 2:
                if state.get(f) == 1:
                    cycle = walk[walk.index(f):] + [f]
                    raise RigError(f"{self.source}: the {self.hop}s form a cycle: {' → '.join(reversed(cycle))}")
                state[f] = 1
                walk.append(f)
                f = self.parent[f].parent
            for w in walk:
                state[w] = 2

    def _in_root(self, frame: str) -> tuple[str, np.ndarray, np.ndarray]:
        """(root, R, p): the pose of ``frame`` in its tree's root (memoised along the way)."""
        walk, f = [], frame
        while f in self.parent and f not in self._root:
            walk.append(f)
            f = self.parent[f].parent
        root, R, p = self._root.get(f, (f, np.eye(3), np.zeros(3)))
        for g in reversed(walk):
            h = self.parent[g]
            R, p = R @ h.R, R @ h.p + p
            self._root[g] = (root, R, p)
        return root, R, p

    def pose(self, a: str, b: str) -> tuple[np.ndarray, np.ndarray]:
        """The pose of frame ``b`` in frame ``a``."""
        frames = self.frames
        for f in (a, b):
            if f not in frames:
                listed = sorted(frames)
                shown = ", ".join(listed[:40]) + (f", … ({len(listed)} frames)" if len(listed) > 40 else "")
                raise RigError(f"{self.source}: frame {f!r} is in no {self.hop} (frames: {shown})")
        ra, Ra, pa = self._in_root(a)
        rb, Rb, pb = self._in_root(b)
        if ra != rb:
            raise RigError(f"{self.source}: no {self.hop} links {a!r} and {b!r}: {a!r} hangs from {ra!r} and "
                           f"{b!r} from {rb!r}")
        return Ra.T @ Rb, Ra.T @ (pb - pa)


def classify(frames: Iterable[str]) -> dict[str, list[str]]:
    """Frames by the kind their names say (lidar, camera, gnss, imu); others are left out."""
    out: dict[str, list[str]] = {"lidar": [], "camera": [], "gnss": [], "imu": []}
    for f in sorted(frames):
        kind = ("imu" if IMU.search(f) else "gnss" if GNSS.search(f) else "lidar" if LIDAR.search(f)
                else "camera" if CAMERA.search(f) else None)
        if kind:
            out[kind].append(f)
    return out


def gnss_frames(tree: Tree, exclude: set[str]) -> list[str]:
    """The frames of a tree named like a GNSS antenna (``gnss``, ``gps_link`` …), but ``exclude``."""
    return sorted(f for f in tree.frames - exclude if GNSS.search(f))


def rig_from_tree(tree: Tree, *, imu: str, base: str, lidar: list[str], camera: list[str],
                  gnss: list[str] | None, name: str, notes: list[str],
                  rates: dict[str, float] | None = None) -> common.ImportedRig:
    """The rig of a tree: B = ``imu``, V = ``base``, a sensor at each named frame (named after its
    frame); GNSS antennas at ``gnss`` (None: every frame named like one). ``rates`` gives the
    frames' rates where the source tells them."""
    rates = rates or {}
    R_V_B, p_V_B = tree.pose(base, imu)
    if gnss is None:
        gnss = gnss_frames(tree, {imu, base, *lidar, *camera})
    review: dict[str, str] = {}
    sensors: list[dict] = []
    taken: set[str] = set()
    named = []
    for kind, frames in (("lidar", lidar), ("camera", camera), ("gnss", gnss)):
        for frame in frames:
            R, p = tree.pose(imu, frame)
            sname = common.unique(common.frame_name(frame, kind), taken)
            i = len(sensors)
            if kind == "gnss":
                sensors.append(common.gnss_sensor(sname, p, review, i))
            else:
                sensors.append(common.odometry_sensor(sname, kind, R, p, review, i, rate_hz=rates.get(frame)))
            named.append(f"{sname} = {frame}")
    cfg = {"name": name, "imu": common.default_imu(review), "vehicle": {"T_V_B": common.pose(R_V_B, p_V_B)},
           "sensors": sensors, "targets": common.default_targets(sensors)}
    review["targets"] = common.targets_review()
    return common.finish(cfg, review, notes + [f"B = {imu}, V = {base}"] + named, tree.source)
