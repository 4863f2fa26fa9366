"""``--scene``: the scene a command's drives are scored in (:mod:`excite.scene`).

Every command that evaluates a drive (``score``, ``live``, ``mine``, ``validate``, ``batch``) takes
``--scene FILE`` — a scene file (GeoJSON, a mesh, a point-cloud map) or a bundled scene's name —
read by :func:`excite.scene.files.load_scene` and seen along each drive before it is evaluated
(:func:`excite.scene.along.seen`): the rig's lidars are then told what the surfaces in view can
tell. A scene that cannot be read is the command's one-line error naming the file.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import typer

if TYPE_CHECKING:
    from ..motion.trajectory import Trajectory
    from ..scene.model import Scene

HELP = ("Score the drive in this scene: a scene file (.geojson, .ply, .obj, .stl, .pcd, .las, .laz) or a "
        "bundled scene's name (excite scene list); the rig's lidars see its surfaces along the drive.")


def load(ref: str | None) -> "Scene | None":
    """The scene ``ref`` names (None: none)."""
    if ref is None:
        return None
    from ..scene.files import load_scene

    return load_scene(ref)


def warn_blind(rig: Any, scene: "Scene | None") -> None:
    """On stderr: a scene given to a rig without a lidar changes nothing."""
    if scene is not None and not any(s.kind == "lidar" for s in rig.config.sensors):
        typer.secho(f"warning: rig {rig.name} has no lidar: the scene {scene.source} changes nothing", err=True,
                    fg="yellow")


def seeing(traj: "Trajectory", rig: Any, scene: "Scene | None") -> "Trajectory":
    """``traj`` seeing ``scene`` with ``rig``'s lidars (``traj`` itself without a scene)."""
    if scene is None:
        return traj
    from ..scene.along import seen

    return seen(traj, rig, scene)


def line(scene: dict[str, str] | None) -> str | None:
    """How a report's text names its scene (None: none)."""
    if scene is None:
        return None
    from ..score.evaluate import scene_text

    return scene_text(scene)
