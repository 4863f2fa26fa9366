"""``POST /v1/maneuvers``: plan a calibration maneuver (an asynchronous job)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Response

from excite.errors import ExciteError
from excite.plan import OptimizeSettings
from excite.motion.vehicle import Limits

from ..auth import Planner
from ..context import Ctx
from ..errors import ProblemError, Rejected
from ..schemas import Job, ManeuverRequest
from ..scoring import lot_task, resolve_rig
from .common import BODY
from .jobs import job_view

router = APIRouter(prefix="/v1", tags=["maneuvers"])


@router.post("/maneuvers", status_code=202, response_model=Job, responses=BODY,
             summary="Plan a maneuver: accepted as a job, persisted before the answer")
def create_maneuver(body: ManeuverRequest, ctx: Ctx, response: Response, who: Planner) -> Any:
    """Returns ``202`` with the job and its ``Location``; poll ``GET /v1/jobs/{id}``. A key may
    have at most its quota of jobs queued and running (429 with ``Retry-After`` beyond)."""
    s = ctx.settings
    errors: list[dict[str, str]] = []  # every refused field at once, so a form can mark them all
    if body.duration_s > s.max_route_duration_s:
        errors.append({"field": "duration_s", "message": f"{body.duration_s:g} s is over the limit of "
                                                         f"{s.max_route_duration_s:g} s"})
    if body.time_budget_s > s.max_job_time_budget_s:
        errors.append({"field": "time_budget_s", "message": f"{body.time_budget_s:g} s is over the limit of "
                                                            f"{s.max_job_time_budget_s:g} s"})
    if body.lot is not None:  # checked in a scoring worker: its memory limit applies
        (fut,) = ctx.submit(lot_task, [(body.lot, s.max_lot_vertices)], ctx.deadline())
        (why,) = ctx.wait([fut])
        if why is not None:
            errors.append({"field": "lot", "message": why})
    try:
        OptimizeSettings(duration_s=body.duration_s, lot_x_m=body.lot_x_m,
                         lot_y_m=body.lot_y_m, limits=Limits(**body.limits.model_dump()),
                         seed=body.seed, time_budget_s=body.time_budget_s, closed=body.closed,
                         n_random=body.n_random, criterion=body.criterion)
    except ExciteError as exc:  # the optimizer's own bounds, checked now rather than in a failed job
        errors.append({"field": str(exc).split(" ", 1)[0], "message": str(exc)})
    try:
        resolve_rig(body.rig)
    except Rejected as exc:
        if exc.status != 422:
            raise ProblemError(exc.status, f"{exc.field}: {exc.message}",
                               errors=[{"field": exc.field, "message": exc.message}]) from None
        errors.append({"field": exc.field, "message": exc.message})
    if errors:
        raise ProblemError(422, "; ".join(e["message"] if e["message"].startswith(e["field"]) else
                                          f"{e['field']}: {e['message']}" for e in errors), errors=errors)
    if who.limits is not None and ctx.store.active(who.key_id) >= who.limits.jobs:
        raise ProblemError(429, f"the key {who.key_id} has {who.limits.jobs} jobs queued or running "
                                "already (its quota); retry when one has finished",
                           type_="quota", headers={"Retry-After": "30"})
    job_id = ctx.store.create("maneuver", body.model_dump(), key_id=who.key_id, owner=who.owner)
    ctx.runner.wake()
    response.headers["Location"] = f"/v1/jobs/{job_id}"
    return job_view(ctx.store.get(job_id))
