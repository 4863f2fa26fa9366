"""``POST /v1/batch``: many routes, one report (or problem) each, and a summary."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from ..auth import Scorer
from ..context import Ctx
from ..errors import ProblemError
from ..schemas import BatchRequest, BatchResponse
from .common import SCORED

router = APIRouter(prefix="/v1", tags=["batch"])


@router.post("/batch", response_model=BatchResponse, responses=SCORED,
             summary="Score many routes with one rig (a CI gate's call)")
def batch(body: BatchRequest, ctx: Ctx, who: Scorer) -> Any:
    """Each route gets its report, or a problem naming its field (``routes[3].text``); one bad
    route does not fail the others. ``summary.passed`` counts reports whose every parameter meets
    its target."""
    n_max = ctx.settings.max_batch_routes
    if len(body.routes) > n_max:
        raise ProblemError(422, f"routes: {len(body.routes)} routes exceed the limit of {n_max}",
                           errors=[{"field": "routes", "message": f"at most {n_max} routes"}])
    limits = body.limits.model_dump() if body.limits else None
    deadline = ctx.deadline()
    futures = ctx.submit_batch_scores([(r.model_dump(), f"routes[{i}]") for i, r in enumerate(body.routes)],
                                      body.rig, body.segments, limits, deadline)
    results = ctx.wait(futures)
    items, scores, passed, failed, errors = [], [], 0, 0, 0
    for i, (route, res) in enumerate(zip(body.routes, results)):
        if res["ok"]:
            rep = res["report"]
            scores.append(rep["score"])
            passed += bool(rep["passed"])
            failed += not rep["passed"]
            items.append({"index": i, "name": route.name or rep["route"], "report": rep, "error": None})
        else:
            errors += 1
            status = res["status"]
            detail = res["detail"] if status < 500 else "internal error (logged)"
            items.append({"index": i, "name": route.name, "report": None, "error": {
                "type": "https://excite.dev/problems/" + ("validation" if status == 422 else
                                                          "too-large" if status == 413 else "internal"),
                "title": "Route not scored", "status": status, "detail": detail,
                "instance": f"/v1/batch#routes[{i}]", "errors": res["errors"]}})
    return {"summary": {"count": len(items), "passed": passed, "failed": failed, "errors": errors,
                        "min_score": min(scores) if scores else None},
            "results": items}
