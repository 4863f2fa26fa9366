"""Probes and metrics: ``/healthz`` (the process answers), ``/readyz`` (it can do work: :func:`unready`
says why not), ``/metrics`` (Prometheus text, never failing; who may read it is ``EXCITE_METRICS``)."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from fastapi import APIRouter, FastAPI, Security
from fastapi.responses import Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from ..auth import authorize
from ..context import Ctx, Context
from ..errors import Problem
from ..schemas import Health
from ..store import ACTIVE, FINAL
from .common import AUTH, problems

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness")
async def healthz() -> Any:
    return {"status": "ok"}


def free_mb(path: Path) -> float:
    """Free space [MiB] on the disk that holds ``path`` (or its nearest existing parent)."""
    while not path.exists() and path != path.parent:
        path = path.parent
    return shutil.disk_usage(path).free / 2**20


def unready(ctx: Context) -> str | None:
    """Why the server cannot do its work now, or None."""
    try:
        ctx.store.ping()
    except Exception as exc:
        return f"the job store does not answer ({type(exc).__name__})"
    if ctx.runner.fault is not None:
        return "the job store failed the dispatcher's last use of it (the fault is logged)"
    need = ctx.settings.min_free_mb
    folders = [Path(tempfile.gettempdir())]
    if ctx.store.path is not None:
        folders.insert(0, ctx.store.path.parent)
    for folder in folders:
        try:
            left = free_mb(folder)
        except OSError:
            return f"cannot tell the free space of {folder}"
        if left < need:
            which = "job database's" if folder is not folders[-1] else "temporary folder's"
            return f"the {which} disk has {left:.0f} MiB free, under EXCITE_MIN_FREE_MB ({need})"
        if not os.access(folder, os.W_OK):
            return f"the {folder} folder is not writable"
    if not ctx.pool.ready:
        return "the scoring workers are starting"
    if ctx.settings.workers and not ctx.runner.alive:
        return "the job dispatcher is not running"
    return None


@router.get("/readyz", response_model=Health, responses=problems(503), summary="Readiness")
def readyz(ctx: Ctx) -> Any:
    """Ready when the job store answers, there is disk space, the scoring workers are up and
    jobs are dispatched."""
    why = unready(ctx)
    if why is not None:
        raise Problem(503, why, headers={"Retry-After": "5"})
    detail = {} if ctx.keys is not None else {
        "score_workers": ctx.settings.score_workers, "job_workers": ctx.settings.workers,
        "jobs_running": ctx.runner.running}
    return {"status": "ready", "detail": detail}


def add_metrics(app: FastAPI, access: str) -> None:
    """``GET /metrics`` for everyone (``public``), admin keys (``admin``) or no one (``off``)."""
    if access == "off":
        return

    def metrics(ctx: Ctx) -> Response:  # the store's state and job counts as far as the store answers
        try:
            counts = ctx.store.counts()
        except Exception:
            ctx.store_up.set(0)
        else:
            ctx.store_up.set(1)
            for status in ACTIVE + FINAL:
                ctx.jobs_gauge.labels(status).set(counts.get(status, 0))
        return Response(generate_latest(ctx.registry), media_type=CONTENT_TYPE_LATEST)

    app.add_api_route("/metrics", metrics, methods=["GET"], response_class=Response, tags=["health"],
                      summary="Prometheus metrics",
                      dependencies=[Security(authorize, scopes=["admin"])] if access == "admin" else [],
                      responses={200: {"content": {"text/plain": {"schema": {"type": "string"}}},
                                       "description": "Prometheus text exposition format"},
                                 **(AUTH if access == "admin" else {})})
