"""``excite scene``: what a scene holds and where in it a lidar is degenerate (:mod:`excite.scene`)."""

from __future__ import annotations

import json
from typing import Annotated, Any, Optional

import typer

from .app import app, console

scene_app = typer.Typer(no_args_is_help=True, help="Scenes: what a scene holds and where in it a lidar is "
                                                   "degenerate; the bundled scenes.")
app.add_typer(scene_app, name="scene")


def _m(x: float) -> str:
    return f"{x:.0f}" if abs(x) >= 10 else f"{x:.1f}"


def print_info(doc: dict[str, Any], lidar: str, out: Any) -> None:
    """The survey (:meth:`excite.scene.survey.Survey.to_dict`) for a terminal."""
    sc, sv = doc["scene"], doc["survey"]
    lo, hi = doc["bounds_m"]["min"], doc["bounds_m"]["max"]
    out.print(f"{sc['name']} (sha256 {sc['digest'][:12]}): {doc['triangles']} triangles, {doc['surfaces']} surfaces")
    out.print("extent: " + ", ".join(f"{a} {_m(lo[i])} … {_m(hi[i])} m ({_m(hi[i] - lo[i])} m)"
                                     for i, a in enumerate("xyz")))
    out.print("by kind: " + ", ".join(f"{k} {doc['surfaces_by_kind'][k]} ({doc['area_m2_by_kind'][k]:,.0f} m²)"
                                      for k in doc["area_m2_by_kind"]))
    spacing = f"every {sv['spacing_m']:g} m" + (f" (widened from {sv['asked_spacing_m']:g} m to bound the grid)"
                                               if sv["spacing_m"] != sv["asked_spacing_m"] else "")
    ref = sv["reference_sigma"]
    out.print(f"where a lidar ({lidar}, level, {sv['height_m']:g} m above the ground) is degenerate, and along what: "
              f"one scan {spacing}; weak: σ from one scan above {ref['translation_m'] * 100:g} cm or "
              f"{ref['rotation_rad'] * 57.29577951308232:.2g}° (a lidar odometry's drift per scan pair)",
              overflow="fold")
    ys = sv["y_m"][::-1]
    width = max(len(_m(y)) for y in ys)
    for y, row in zip(ys, sv["map"]):
        out.print(f"{_m(y):>{width}} {row}", markup=False, highlight=False, overflow="ignore", crop=False,
                  soft_wrap=True)
    xs = sv["x_m"]
    axis = f"{_m(xs[0])} m"
    end = f"{_m(xs[-1])} m"
    out.print(" " * (width + 1) + axis + " " * max(1, len(xs) - len(axis) - len(end)) + end + "  (x →, y ↑)",
              markup=False, highlight=False, soft_wrap=True)
    for item in sv["legend"]:
        out.print(f"  {item['symbol']}  {item['meaning']} ({item['cells']} points)", markup=False,
                  highlight=False, overflow="fold")


@scene_app.command("info")
def info(
    scene: Annotated[str, typer.Argument(help="A scene file (.geojson, .ply, .obj, .stl, .pcd, .las, .laz) or a "
                                              "bundled scene's name.")],
    spacing: Annotated[float, typer.Option(help="Distance between the scans of the map [m] (widened for a "
                                                "large scene: at most 3000 scans, 160 across).")] = 5.0,
    height: Annotated[float, typer.Option(help="The lidar's height above the ground [m].")] = 1.8,
    lidar: Annotated[Optional[str], typer.Option(help="The lidar's beams: a preset's name (default: the rigs' "
                                                      "default lidar).")] = None,
    json_out: Annotated[bool, typer.Option("--json", help="Print the survey as JSON (every scan's reading).")] = False,
) -> None:
    """The scene's extent, its triangles and surfaces by kind, and a map of where in it a lidar
    is degenerate and along what (a scan ray-cast on a grid over the scene)."""
    from ..errors import SceneError
    from ..factors.optics import DEFAULT_LIDAR, LIDAR_PRESETS
    from ..scene.files import load_scene
    from ..scene.survey import survey

    if lidar is not None and lidar not in LIDAR_PRESETS:
        raise SceneError(f"--lidar: no preset {lidar!r} (presets: {', '.join(LIDAR_PRESETS)})")
    s = survey(load_scene(scene), spacing, height, lidar)
    doc = s.to_dict()
    if json_out:
        typer.echo(json.dumps(doc))
    else:
        print_info(doc, lidar or DEFAULT_LIDAR, console())


@scene_app.command("list")
def scene_list() -> None:
    """Names of the bundled scenes."""
    from ..scene.files import bundled_scenes

    for n in bundled_scenes():
        typer.echo(n)
