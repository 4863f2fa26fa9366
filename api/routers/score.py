"""``POST /v1/score``: one route and a rig → the evaluator's report."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.responses import Response

from ..context import Ctx, raise_problem
from ..schemas import PlotRequest, Report, ScoreRequest
from .common import BODY

router = APIRouter(prefix="/v1", tags=["score"])


@router.post("/score", response_model=Report, responses=BODY,
             summary="Score a route: how well does it determine every calibration parameter?")
def score(body: ScoreRequest, ctx: Ctx) -> Any:
    """The route is given inline (file text with its format, JSON waypoints, timed poses or a
    control profile); the rig by bundled name or inline. CPU-bound: runs in a worker process."""
    limits = body.limits.model_dump() if body.limits else None
    fut = ctx.submit_score(body.route.model_dump(), body.rig, body.segments, limits, ctx.deadline())
    (result,) = ctx.wait([fut])
    if not result["ok"]:
        raise_problem(result)
    return result["report"]


@router.post("/score/plot", response_class=Response, summary="The report of a route as a figure (PNG)",
             responses={**BODY, 200: {"content": {"image/png": {}},
                                      "description": "route coloured by information, scaled spectrum, σ/target"}})
def score_plot(body: PlotRequest, ctx: Ctx) -> Response:
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
