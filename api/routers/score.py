"""``POST /v1/score``: one route and a rig → the evaluator's report; ``/v1/score/plot`` its
figure; ``/v1/score/bag``: a recorded bag (multipart upload) → its report."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Annotated, Any, Callable

from fastapi import APIRouter, File, Form, Request, UploadFile
from fastapi.responses import Response

from ..auth import Principal, Scorer
from ..context import Context, Ctx
from ..errors import Problem
from ..schemas import SCENE_PATTERN, PlotRequest, Report, RouteScoring, ScoreRequest, ScoreResponse
from ..scoring import SCENE_WORK, bag_score_task, plot_task, scene_spec, score_task, work_size
from .common import BODY

router = APIRouter(prefix="/v1", tags=["score"])


@router.post("/score", response_model=ScoreResponse, responses=BODY,
             summary="Score a route: how well does it determine every calibration parameter?")
def score(body: ScoreRequest, request: Request, ctx: Ctx, who: Scorer) -> Any:
    """The route is given inline (file text with its format, JSON waypoints, timed poses or a
    control profile); the rig by bundled name or inline; the scene, if any, by a bundled name or
    the digest of one uploaded with ``POST /v1/scenes``. CPU-bound: runs in a worker process.
    A recorded bag is scored by ``POST /v1/score/bag``."""
    out = _scored(body, request, ctx, who, score_task, body.track_points)
    return {**out["report"], "track": out.get("track"), "scene_track": out.get("scene_track")}


@router.post("/score/plot", response_class=Response, summary="The report of a route as a figure (PNG)",
             responses={**BODY, 200: {"content": {"image/png": {}},
                                        "description": "route coloured by information, scaled spectrum, σ/target"}})
def score_plot(body: PlotRequest, request: Request, ctx: Ctx, who: Scorer) -> Response:
    """The same figure as ``excite score ROUTE --plot FILE.png``: the route coloured by the
    information it carries on ``parameter`` (or the weakest mode), the scaled spectrum with the
    pass line, and σ against target per parameter."""
    return Response(content=_scored(body, request, ctx, who, plot_task, body.parameter), media_type="image/png")


def _scored(body: RouteScoring, request: Request, ctx: Context, who: Principal, fn: Callable[..., Any],
            *extra: Any) -> Any:
    """``fn(route, rig, segments, limits, bounds, scene, *extra)`` of the request in a scoring worker."""
    route = body.route.model_dump()
    scene = scene_spec(ctx.store, who.key_id, body.scene)
    return ctx.run(request, who, fn, route, body.rig, body.segments, body.limits.model_dump() if body.limits else None,
                   ctx.bounds, scene, *extra, size=work_size(route, scene))


def _rig_field(text: str) -> str | dict[str, Any]:
    if not text.lstrip().startswith("{"):
        return text
    try:
        rig = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        why = exc.msg if isinstance(exc, json.JSONDecodeError) else "nested too deeply"
        raise Problem.at("rig", f"not valid JSON ({why})") from None
    if not isinstance(rig, dict):
        raise Problem.at("rig", "expected a rig object")
    return rig


@router.post("/score/bag", response_model=Report, responses=BODY,
             summary="Score a recorded drive: a ROS 1 bag or an MCAP file (multipart upload)")
def score_bag(request: Request, ctx: Ctx, who: Scorer,
              bag: Annotated[UploadFile, File(description="The .bag or .mcap file.")],
              topic: Annotated[str, Form(min_length=1, max_length=1000,
                                         description="Pose topic, or a TF chain /tf:PARENT.CHILD.")],
              imu_topic: Annotated[str | None, Form(max_length=1000, description="IMU topic (checked).")] = None,
              rig: Annotated[str, Form(max_length=1_000_000,
                                       description="A bundled rig's name or a rig object as JSON.")] = "robotaxi",
              start_s: Annotated[float | None, Form(allow_inf_nan=False, description="Start [s into the bag].")] = None,
              end_s: Annotated[float | None, Form(allow_inf_nan=False, description="End [s into the bag].")] = None,
              segments: Annotated[int, Form(ge=0, le=1000)] = 0,
              vehicle_frame: Annotated[str | None, Form(max_length=200)] = None,
              axes: Annotated[str, Form(max_length=40, description="vehicle or body.")] = "vehicle",
              scene: Annotated[str | None, Form(pattern=SCENE_PATTERN, description=(
                  "A bundled scene's name or the digest of one uploaded with POST /v1/scenes."))] = None) -> Any:
    """The upload is written to disk once, as it arrives (within the body limit; a server whose
    temporary folder is nearly full answers 503), read by the worker through a link named as its
    kind, and deleted after scoring; a truncated or corrupt bag is a 422 naming the problem."""
    from .health import free_mb

    filename = Path(bag.filename or "").name
    suffix = Path(filename).suffix.lower()
    if suffix not in (".bag", ".mcap"):
        raise Problem.at("bag", f"the file name must end in .bag or .mcap, got {filename[:200]!r}")
    rig_value = _rig_field(rig)
    world = scene_spec(ctx.store, who.key_id, scene or None)
    if free_mb(Path(tempfile.gettempdir())) < ctx.settings.min_free_mb:
        raise Problem(503, "the server's temporary folder is nearly full; retry later", type_="disk-full",
                      headers={"Retry-After": "30"})
    source = {"topic": topic, "imu_topic": imu_topic or None, "start_s": start_s, "end_s": end_s,
              "vehicle_frame": vehicle_frame or None, "axes": axes}
    with tempfile.TemporaryDirectory(prefix="excite-bag-") as tmp:
        # the spooled upload (on disk once: fileno() moves a small one there) under the name of
        # its kind, which the bag readers go by: a link to this process's descriptor of it
        path = Path(tmp) / f"upload{suffix}"
        os.symlink(f"/proc/{os.getpid()}/fd/{bag.file.fileno()}", path)
        try:
            return ctx.run(request, who, bag_score_task, str(path), filename, source, rig_value, segments,
                           ctx.bounds, world, size=(SCENE_WORK if world else 1.0) *
                           max(1.0, os.fstat(bag.file.fileno()).st_size / 20_000))
        finally:
            bag.file.close()
