"""``/v1/scenes``: a scene file uploaded once (read by :func:`api.scoring.scene_file_task`, kept
by :meth:`api.store.JobStore.put_scene`) and named by its digest in the score requests after
(:func:`api.scoring.scene_spec`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, File, Request, Response, UploadFile

from excite.scene.files import SUFFIXES, bundled_scenes

from ..auth import Scorer
from ..context import Ctx, deadline
from ..errors import Problem
from ..schemas import SceneList, SceneSummary, SceneView
from ..scoring import DIGEST, scene_file_task, scene_spec, scene_view_task
from .common import AUTH, BODY, problems

router = APIRouter(prefix="/v1", tags=["scenes"])


@router.post("/scenes", status_code=201, response_model=SceneSummary,
             responses={**BODY, 200: {"model": SceneSummary, "description": "The key has this scene already"}},
             summary="Upload a scene file: kept under the digest that score requests name it by")
def upload_scene(request: Request, ctx: Ctx, response: Response, who: Scorer,
                 file: Annotated[UploadFile, File(description=(
                     "The scene: GeoJSON (.geojson, .json), a mesh (.ply, .obj, .stl) or a point-cloud map "
                     "(.pcd, .ply, .las, .laz)."))]) -> Any:
    """Read in a worker (a file that cannot be read: 422 naming its field); kept for this key
    (201, ``Location``), or found kept already (200). Its size counts against the key's storage
    quota (429 when the key's unfinished jobs leave no room)."""
    name = Path(file.filename or "").name
    suffix = Path(name).suffix.lower()
    if suffix not in SUFFIXES:
        raise Problem.at("file", f"the file name must end in {', '.join(SUFFIXES)}, got {name[:200]!r}")
    limit = ctx.settings.max_scene_bytes
    try:
        data = file.file.read(limit + 1)
    finally:
        file.file.close()
    if len(data) > limit:
        raise Problem.at("file", f"over the limit of {limit} bytes (EXCITE_MAX_SCENE_BYTES)", 413)
    if not data:
        raise Problem.at("file", "the file is empty")
    summary = ctx.run(request, who, scene_file_task, name, data, size=max(1.0, len(data) / 200_000))
    with deadline(request).commit():  # answered 503 already: nothing kept; keeping it: no 503
        created = ctx.store.put_scene(who.key_id, summary["digest"], name, summary, data,
                                      max_bytes=ctx.storage_bytes(who.key_id))
    if not created:
        response.status_code = 200
    response.headers["Location"] = f"/v1/scenes/{summary['digest']}"
    return ctx.store.scene_summaries(who.key_id, summary["digest"])[0]


@router.get("/scenes", response_model=SceneList, responses=AUTH, summary="The bundled scenes and this key's")
def list_scenes(ctx: Ctx, who: Scorer) -> Any:
    return {"bundled": bundled_scenes(), "uploaded": ctx.store.scene_summaries(who.key_id)}


@router.get("/scenes/{scene}", response_model=SceneView, responses={**AUTH, **problems(404, 422, 503)},
            summary="A scene's summary and its outline from above")
def get_scene(scene: str, request: Request, ctx: Ctx, who: Scorer) -> Any:
    """A bundled scene by its name, or one of this key's by its digest: what it holds and each
    surface's outline seen from above (segments; a surface of too many is given by its bounding
    rectangle)."""
    if scene not in bundled_scenes() and not (DIGEST.match(scene) and ctx.store.scene_summaries(who.key_id, scene)):
        raise Problem(404, f"no scene {scene[:64]!r}: neither bundled nor uploaded with this key")
    spec = scene_spec(ctx.store, who.key_id, scene)
    upload = spec[0] == "upload"
    out = ctx.run(request, who, scene_view_task, spec, spec[2] if upload else scene,
                  size=max(1.0, len(spec[3]) / 200_000) if upload else 1.0)
    return {**out, **ctx.store.scene_summaries(who.key_id, scene)[0]} if upload else out


@router.delete("/scenes/{scene}", status_code=204, responses={**AUTH, **problems(404)},
               summary="Delete one of this key's scenes")
def delete_scene(scene: str, ctx: Ctx, who: Scorer) -> Response:
    if not (DIGEST.match(scene) and ctx.store.delete_scene(who.key_id, scene)):
        raise Problem(404, f"no scene {scene[:64]!r} uploaded with this key")
    return Response(status_code=204)
