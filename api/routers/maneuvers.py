"""``POST /v1/maneuvers``: plan a calibration maneuver (an asynchronous job)."""

from __future__ import annotations

import json
from typing import Any

from fastapi import APIRouter, Request, Response

from excite.errors import ExciteError

from ..auth import Planner
from ..context import Ctx, deadline
from ..errors import Problem
from ..schemas import Job, ManeuverRequest
from ..scoring import drivable_check_task, lot_task, optimize_settings, scene_spec
from .common import BODY
from .jobs import job_view

router = APIRouter(prefix="/v1", tags=["maneuvers"])
MAX_STORED_REQUEST_BYTES = 1 << 20  # a request with an inline rig and a GeoJSON lot is a few KiB


@router.post("/maneuvers", status_code=202, response_model=Job, responses=BODY,
             summary="Plan a maneuver: accepted as a job, persisted before the answer")
def create_maneuver(body: ManeuverRequest, request: Request, ctx: Ctx, response: Response, who: Planner) -> Any:
    """Returns ``202`` with the job and its ``Location``; poll ``GET /v1/jobs/{id}``. A key may
    have at most its quota of jobs queued and running, and of storage (429 with ``Retry-After``
    beyond). A request answered 503 (past its time limit) has created no job."""
    s = ctx.settings
    errors: list[dict[str, str]] = []  # every refused field at once, so a form can mark them all
    for field, value, limit in (("duration_s", body.duration_s, s.max_route_duration_s),
                                ("time_budget_s", body.time_budget_s, s.max_job_time_budget_s)):
        if value > limit:
            errors.append({"field": field, "message": f"{value:g} s is over the limit of {limit:g} s"})
    data = body.model_dump()
    try:
        optimize_settings(data)
    except ExciteError as exc:  # the optimizer's own bounds, checked now rather than in a failed job
        errors.append({"field": str(exc).split(" ", 1)[0], "message": str(exc)})
    if body.lot is not None or isinstance(body.rig, dict):  # a client's lot and rig: in a worker
        errors += ctx.run(request, who, lot_task, body.lot, s.max_lot_vertices, body.rig)
    scene = None
    if body.scene is not None and not body.drivable:
        errors.append({"field": "scene", "message": "plans in a scene with drivable: true (the free-form "
                                                    "optimizer plans scene-blind)"})
    elif body.scene is not None:
        try:
            scene = scene_spec(ctx.store, who.key_id, body.scene)
        except Problem as exc:
            errors += exc.errors or []
    if body.drivable and not errors:  # the lot's room for an element, its safe speed, the scene over it
        errors += ctx.run(request, who, drivable_check_task, data, scene)
    if errors:
        raise Problem(422, "; ".join(e["message"] if e["message"].startswith(e["field"]) else
                                     f"{e['field']}: {e['message']}" for e in errors), errors=errors)
    if len(json.dumps(data)) > MAX_STORED_REQUEST_BYTES:
        raise Problem.at("body", f"the request would be stored as more than {MAX_STORED_REQUEST_BYTES} bytes", 413)
    limits = who.limits
    with deadline(request).commit():  # answered 503 already: no job; creating it: no 503
        job_id = ctx.store.create("maneuver", data, key_id=who.key_id, owner=who.owner,
                                  max_active=None if limits is None else limits.jobs,
                                  max_bytes=ctx.storage_bytes(who.key_id))
    ctx.runner.wake()
    response.headers["Location"] = f"/v1/jobs/{job_id}"
    return job_view(ctx.store.get(job_id))
