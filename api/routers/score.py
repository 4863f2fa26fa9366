"""``POST /v1/score``: one route and a rig → the evaluator's report."""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from typing import Any

import anyio
from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response
from fastapi.routing import APIRoute
from starlette.datastructures import UploadFile
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match

from ..auth import Scorer
from ..context import Ctx, raise_problem
from ..errors import ProblemError
from ..scoring import bag_score_task
from ..schemas import PlotRequest, ScoreRequest, ScoreResponse
from .common import SCORED

router = APIRouter(prefix="/v1", tags=["score"])


@router.post("/score", response_model=ScoreResponse, responses=SCORED,
             summary="Score a route: how well does it determine every calibration parameter?")
def score(body: ScoreRequest, ctx: Ctx, who: Scorer) -> Any:
    """The route is given inline (file text with its format, JSON waypoints, timed poses or a
    control profile); the rig by bundled name or inline. CPU-bound: runs in a worker process.

    A bag is scored by posting it to the same path as ``multipart/form-data``: fields ``bag``
    (the ``.bag`` or ``.mcap`` file), ``topic`` (pose topic or TF chain ``/tf:PARENT.CHILD``),
    optional ``imu_topic``, ``rig`` (bundled name or inline JSON), ``start_s``, ``end_s``,
    ``segments``, ``vehicle_frame``, ``axes``. The upload is spooled to disk within the body
    limit; a truncated or corrupt bag is a 422 naming the problem."""
    limits = body.limits.model_dump() if body.limits else None
    futures = ctx.submit_scores([(body.route.model_dump(), "route")], body.rig, body.segments, limits,
                                ctx.deadline(), track_points=body.track_points)
    (result,) = ctx.wait(futures)
    if not result["ok"]:
        raise_problem(result)
    return {**result["report"], "track": result.get("track")}


@router.post("/score/plot", response_class=Response, summary="The report of a route as a figure (PNG)",
             responses={**SCORED, 200: {"content": {"image/png": {}},
                                      "description": "route coloured by information, scaled spectrum, σ/target"}})
def score_plot(body: PlotRequest, ctx: Ctx, who: Scorer) -> Response:
    """The same figure as ``excite score ROUTE --plot FILE.png``: the route coloured by the
    information it carries on ``parameter`` (or the weakest mode), the scaled spectrum with the
    pass line, and σ against target per parameter."""
    limits = body.limits.model_dump() if body.limits else None
    fut = ctx.submit_plot(body.route.model_dump(), body.rig, body.segments, limits, body.parameter,
                          ctx.deadline())
    (result,) = ctx.wait([fut])
    if not result["ok"]:
        raise_problem(result)
    return Response(content=result["png"], media_type="image/png")


# --------------------------------------------------------------------------------------------
# Bag uploads: the same path, multipart/form-data


class _MultipartRoute(APIRoute):
    """Matches only multipart requests, so that ``POST /v1/score`` takes a JSON route or a bag
    upload by its content type (this route is registered first)."""

    def matches(self, scope: dict) -> tuple[Match, dict]:
        headers = dict(scope.get("headers", []))
        if not headers.get(b"content-type", b"").lower().startswith(b"multipart/form-data"):
            return Match.NONE, {}
        return super().matches(scope)


bag_router = APIRouter(prefix="/v1", tags=["score"], route_class=_MultipartRoute)
_BAG_SUFFIXES = (".bag", ".mcap")
_FIELDS = ("bag", "topic", "imu_topic", "rig", "start_s", "end_s", "segments", "vehicle_frame", "axes")


def _number(form: Any, key: str, kind: type) -> Any:
    value = form.get(key)
    if value is None or value == "":
        return None
    try:
        x = kind(value)
    except (TypeError, ValueError):
        raise ProblemError(422, f"{key}: expected a number, got {value!r}",
                           errors=[{"field": key, "message": "expected a number"}]) from None
    if not math.isfinite(x):
        raise ProblemError(422, f"{key}: must be finite", errors=[{"field": key, "message": "must be finite"}])
    return x


def _invalid(key: str, message: str) -> ProblemError:
    return ProblemError(422, f"{key}: {message}", errors=[{"field": key, "message": message}])


@bag_router.post("/score", include_in_schema=False)
async def score_bag(request: Request, ctx: Ctx, who: Scorer) -> Any:
    """A bag upload (multipart/form-data): ``bag`` (a ``.bag`` or ``.mcap`` file), ``topic``
    (pose topic or ``/tf:PARENT.CHILD``), optional ``imu_topic``, ``rig`` (bundled name or inline
    JSON), ``start_s``/``end_s``, ``segments``, ``vehicle_frame``, ``axes``. The file is spooled
    to disk as it arrives (within the body limit) and deleted after scoring."""
    try:
        async with request.form(max_files=1, max_fields=len(_FIELDS)) as form:
            return await _score_form(form, ctx)
    except StarletteHTTPException as exc:
        raise ProblemError(400, f"the multipart body cannot be parsed ({exc.detail})") from None


async def _score_form(form: Any, ctx: Any) -> Any:
    """Validate the form, spool the bag to a temporary file, score it in a worker."""
    unknown = [k for k in form.keys() if k not in _FIELDS]
    if unknown:
        raise _invalid(unknown[0], f"unknown field (fields: {', '.join(_FIELDS)})")
    upload = form.get("bag")
    if not isinstance(upload, UploadFile):
        raise _invalid("bag", "required: the bag file (a ROS 1 .bag or an .mcap)")
    filename = Path(upload.filename or "").name
    suffix = Path(filename).suffix.lower()
    if suffix not in _BAG_SUFFIXES:
        raise _invalid("bag", f"the file name must end in .bag or .mcap, got {filename!r}")
    topic = form.get("topic")
    if not isinstance(topic, str) or not topic:
        raise _invalid("topic", "required: a pose topic or a TF chain /tf:PARENT.CHILD")
    rig_text = form.get("rig") or "robotaxi"
    if not isinstance(rig_text, str):
        raise _invalid("rig", "expected a bundled rig name or the rig as JSON text")
    rig: Any = rig_text
    if rig_text.lstrip().startswith("{"):
        try:
            rig = json.loads(rig_text)
        except json.JSONDecodeError as exc:
            raise _invalid("rig", f"not valid JSON ({exc.msg})") from None
    segments = _number(form, "segments", int) or 0
    if not 0 <= segments <= 1000:
        raise _invalid("segments", "must be between 0 and 1000")
    source = {"topic": topic, "imu_topic": form.get("imu_topic") or None,
              "start_s": _number(form, "start_s", float), "end_s": _number(form, "end_s", float),
              "vehicle_frame": form.get("vehicle_frame") or None, "axes": form.get("axes") or "vehicle"}
    with tempfile.TemporaryDirectory(prefix="excite-bag-") as tmp:
        path = Path(tmp) / f"upload{suffix}"
        with path.open("wb") as out:
            while chunk := await upload.read(1 << 20):
                out.write(chunk)
        futures = ctx.submit(bag_score_task, [(str(path), filename, source, rig, segments, ctx.bounds)],
                             ctx.deadline())
        (result,) = await anyio.to_thread.run_sync(ctx.wait, futures)
    if not result["ok"]:
        raise_problem(result)
    return JSONResponse(result["report"])
