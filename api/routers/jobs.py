"""``/v1/jobs/{id}``: status, progress and result of a job; cancel it; download its maneuver."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Path, Query, Request, Response

from ..auth import Planner
from ..context import Ctx
from ..errors import Problem
from ..schemas import Job
from ..scoring import drivable_file_task, maneuver_task
from .common import problems

router = APIRouter(prefix="/v1", tags=["jobs"])

# each download's media type and file suffix: the maneuver's formats, then a drivable plan's files
FILES = {"tum": ("text/plain", "tum"), "csv": ("text/csv", "csv"), "control": ("text/csv", "control.csv"),
         "geojson": ("application/geo+json", "geojson"), "sheet_pdf": ("application/pdf", "sheet.pdf"),
         "sheet_png": ("image/png", "sheet.png"), "cones": ("application/geo+json", "cones.geojson"),
         "plan": ("application/json", "plan.json")}
DRIVABLE = ("sheet_pdf", "sheet_png", "cones", "plan")

JobId = Annotated[str, Path(max_length=64, description="The id returned by POST /v1/maneuvers.")]


def job_view(job: dict[str, Any]) -> dict[str, Any]:
    """The public view of a stored job (the request and the raw profile stay inside)."""
    result, links = job["result"], {"self": f"/v1/jobs/{job['id']}"}
    if result is not None:
        formats = (["tum"] if result.get("profile") is not None else []) + (list(DRIVABLE) if result.get("drivable") else [])
        links.update({"maneuver" if f == "tum" else f: f"/v1/jobs/{job['id']}/maneuver?format={f}" for f in formats})
        result = {k: v for k, v in result.items() if k != "profile"}
    return {"id": job["id"], "kind": job["kind"], "status": job["status"],
            "cancel_requested": bool(job["cancel_requested"]), "created_at": job["created_at"],
            "started_at": job["started_at"], "finished_at": job["finished_at"],
            "attempts": job["attempt"], "progress": job["progress"], "result": result,
            "error": job["error"], "links": links}


def _get(ctx: Ctx, job_id: str, who: Any) -> dict[str, Any]:
    """The job, if ``who`` may see it (its key's, or any for admin): another key's is a 404,
    as if it did not exist."""
    job = ctx.store.get(job_id, key_id=who.job_filter)
    if job is None:
        raise Problem(404, f"no job with id {job_id!r}")
    return job


@router.get("/jobs/{job_id}", response_model=Job, responses=problems(401, 403, 404, 422, 429, 500, 503),
            summary="A job: status, progress (iteration, current score), result when done")
def get_job(job_id: JobId, ctx: Ctx, who: Planner) -> Any:
    return job_view(_get(ctx, job_id, who))


@router.delete("/jobs/{job_id}", response_model=Job, responses=problems(401, 403, 404, 409, 422, 429, 500, 503),
               summary="Cancel a job",
               description="A queued job is cancelled at once (200). A running job is asked to "
                           "stop (202): it finishes as `cancelled`, with the best maneuver so far "
                           "when the optimizer has one. A finished job cannot be cancelled (409).")
def cancel_job(job_id: JobId, ctx: Ctx, response: Response, who: Planner) -> Any:
    status = ctx.store.cancel(job_id, key_id=who.job_filter)
    if status is None:
        raise Problem(404, f"no job with id {job_id!r}")
    if status in ("succeeded", "failed"):
        raise Problem(409, f"job {job_id} already {status}")
    if status == "running":
        response.status_code = 202
        ctx.runner.wake()
    return job_view(_get(ctx, job_id, who))


@router.get("/jobs/{job_id}/maneuver", response_class=Response,
            responses={200: {"description": "The maneuver file",
                             "content": {m: {"schema": {"type": "string"}} for m in
                                         sorted({m for m, _ in FILES.values()})}},
                       **problems(401, 403, 404, 409, 422, 429, 500, 503)},
            summary="Download a job's maneuver as TUM, waypoints CSV, control CSV or GeoJSON; a drivable "
                    "plan's sheet (PDF, PNG), cone layout (GeoJSON) or plan (JSON)")
def download_maneuver(job_id: JobId, request: Request, ctx: Ctx, who: Planner,
                      format: Annotated[Literal["tum", "csv", "control", "geojson", "sheet_pdf", "sheet_png",
                                                "cones", "plan"], Query(
                          description="tum: poses of V; csv: waypoints x,y,z,speed; control: "
                                      "t,speed,curvature CSV; geojson: WGS84 LineString; a drivable plan's "
                                      "sheet_pdf, sheet_png (the driver's sheet), cones (the cone layout, "
                                      "lon/lat where the lot has an origin, else the lot's metres), plan "
                                      "(plan.json)")] = "tum",
                      lon_deg: Annotated[float | None, Query(ge=-180, le=180)] = None,
                      lat_deg: Annotated[float | None, Query(ge=-85, le=85)] = None) -> Response:
    """GeoJSON needs the lot's origin: from the request's ``origin`` or ``lon_deg``/``lat_deg``."""
    job = _get(ctx, job_id, who)
    result = job["result"]
    if result is None or result.get("profile") is None:
        raise Problem(409, f"job {job_id} has no maneuver (status {job['status']})")
    req = ctx.store.request_of(job_id) or {}
    kept = req.get("origin") or result.get("origin")  # the request's, or its lot's (GeoJSON in lon/lat)
    origin = (lon_deg, lat_deg) if lon_deg is not None and lat_deg is not None else (
        kept and (kept["lon_deg"], kept["lat_deg"]))
    name = req.get("name") or "maneuver"
    # the stored rig is a client's: resolved, and the file made, in a worker
    if format in DRIVABLE:
        if not result.get("drivable"):
            raise Problem.at("format", f"{format} is a drivable plan's; job {job_id} planned a free-form maneuver")
        data = ctx.run(request, who, drivable_file_task, result["drivable"]["plan"], req.get("rig", "robotaxi"),
                       format, req.get("lot"), req.get("lot_x_m", 80.0), req.get("lot_y_m", 50.0), origin)
    else:
        if format == "geojson" and origin is None:
            raise Problem.at("lon_deg", "GeoJSON needs the lot's origin: give lon_deg and lat_deg, or origin in the request")
        data = ctx.run(request, who, maneuver_task, result["profile"], req.get("rig", "robotaxi"), format, name, origin)
    media, ext = FILES[format]
    return Response(data, media_type=media, headers={"Content-Disposition": f'attachment; filename="{name}.{ext}"'})
