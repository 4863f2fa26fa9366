"""``POST /v1/batch``: many routes, one report (or problem) each, and a summary."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request

from ..auth import Scorer
from ..context import Ctx
from ..errors import Problem
from ..schemas import BatchRequest, BatchResponse
from ..scoring import batch_item_task, scene_spec, work_size
from .common import BODY

router = APIRouter(prefix="/v1", tags=["batch"])


@router.post("/batch", response_model=BatchResponse, responses=BODY,
             summary="Score many routes with one rig (a CI gate's call)")
def batch(body: BatchRequest, request: Request, ctx: Ctx, who: Scorer) -> Any:
    """Each route gets its report, or a problem naming its field (``routes[3].text``); one bad
    route does not fail the others. ``summary.passed`` counts reports whose every parameter meets
    its target."""
    n_max = ctx.settings.max_batch_routes
    if len(body.routes) > n_max:
        raise Problem.at("routes", f"{len(body.routes)} routes exceed the limit of {n_max}")
    limits = body.limits.model_dump() if body.limits else None
    routes = [r.model_dump() for r in body.routes]
    scene = scene_spec(ctx.store, who.key_id, body.scene)
    results = ctx.run_all(request, who, batch_item_task,
                          [(r, body.rig, body.segments, limits, ctx.bounds, scene, i) for i, r in enumerate(routes)],
                          [work_size(r, scene) for r in routes], cluster=True)
    items, scores, passed = [], [], 0
    for i, (route, res) in enumerate(zip(body.routes, results)):
        rep = res.get("report")
        if rep is not None:
            scores.append(rep["score"])
            passed += bool(rep["passed"])
        items.append({"index": i, "name": route.name or (rep or {}).get("route"), "report": rep,
                      "error": res.get("error")})
    reports = len(scores)
    return {"summary": {"count": len(items), "passed": passed, "failed": reports - passed,
                        "errors": len(items) - reports, "min_score": min(scores) if scores else None},
            "results": items}
