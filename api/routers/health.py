"""Probes and metrics: ``/healthz`` (the process answers), ``/readyz`` (it can do work),
``/metrics`` (Prometheus text)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter
from fastapi.responses import Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from ..context import Ctx
from ..errors import ProblemError
from ..schemas import Health
from .common import problems

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness")
async def healthz() -> Any:
    return {"status": "ok"}


@router.get("/readyz", response_model=Health, responses=problems(503), summary="Readiness")
def readyz(ctx: Ctx) -> Any:
    """Ready when the job store answers, the scoring workers are up and jobs are dispatched."""
    try:
        ctx.store.ping()
    except Exception:
        raise ProblemError(503, "the job store does not answer") from None
    if not ctx.pool.ready:
        raise ProblemError(503, "the scoring workers are starting")
    if ctx.settings.workers and not ctx.runner.alive:
        raise ProblemError(503, "the job dispatcher is not running")
    return {"status": "ready", "detail": {"score_workers": ctx.settings.score_workers,
                                          "job_workers": ctx.settings.workers,
                                          "jobs_running": ctx.runner.running}}


@router.get("/metrics", response_class=Response, summary="Prometheus metrics",
            responses={200: {"content": {"text/plain": {"schema": {"type": "string"}}},
                             "description": "Prometheus text exposition format"}})
def metrics(ctx: Ctx) -> Response:
    gauge = ctx.jobs_gauge
    counts = ctx.store.counts()
    for status in ("queued", "running", "succeeded", "failed", "cancelled"):
        gauge.labels(status).set(counts.get(status, 0))
    return Response(generate_latest(ctx.registry), media_type=CONTENT_TYPE_LATEST)
