"""The app factory: settings → a FastAPI app with its middleware, routers, store and workers.

Start-up opens the job store, re-queues jobs a dead server left running, starts the job
dispatcher and the scoring processes; shutdown stops them and puts running jobs back in the
queue for the next server.
"""

from __future__ import annotations

import logging
import time
from contextlib import asynccontextmanager
from typing import AsyncIterator

import anyio
from fastapi import FastAPI
from prometheus_client import CollectorRegistry, Gauge

from . import problems
from .cluster import ClusterScoring
from .context import Context
from .jobs import JobRunner
from .middleware import BodyLimit, Metrics, TimeLimit
from .routers import batch, health, jobs, live, maneuvers, page, rigs, score
from .pool import WorkerPool
from .scoring import warm
from .settings import Settings
from .store import JobStore

log = logging.getLogger("excite.api")

DESCRIPTION = """\
Score planned or logged drives for how well they determine every sensor calibration parameter
of a rig, plan calibration maneuvers, and gate routes in CI. Errors are
`application/problem+json` (RFC 9457) and name the offending field.
"""


def create_app(settings: Settings | None = None, *,
               job_function: str = "api.jobs:run_optimization") -> FastAPI:
    """The service configured by ``settings`` (default: from the ``EXCITE_*`` environment).

    ``job_function`` (``module:function``) runs one optimization job; tests inject stand-ins
    here, it is not a setting of the service.
    """
    settings = settings or Settings()
    store = JobStore(settings.db_path)
    registry = CollectorRegistry()
    ctx = Context(
        settings=settings, store=store,
        runner=JobRunner(store, settings.workers, job_function, settings.cancel_grace_s,
                         settings.worker_memory_mb, scheduler=settings.dask_scheduler),
        cluster=ClusterScoring(settings.dask_scheduler) if settings.dask_scheduler else None,
        pool=WorkerPool(settings.score_workers, settings.worker_memory_mb,
                        settings.worker_recycle_mb, warm=warm, max_queued=settings.max_queued_tasks),
        registry=registry,
        jobs_gauge=Gauge("excite_jobs", "Jobs in the store by status", ["status"], registry=registry),
        started_at=time.time())

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        ctx.runner.start()
        await anyio.to_thread.run_sync(ctx.pool.start)
        log.info("excite service ready (db %s)", settings.db_path)
        try:
            yield
        finally:
            ctx.runner.stop()
            ctx.pool.close()
            if ctx.cluster is not None:
                ctx.cluster.close()

    app = FastAPI(title="excite", version="1", description=DESCRIPTION, lifespan=lifespan)
    app.state.ctx = ctx
    app.openapi = _openapi_with_settings(app, settings)
    problems.install(app)
    app.include_router(score.bag_router)  # multipart POST /v1/score: before the JSON route
    for module in (score, batch, maneuvers, jobs, rigs, health, page, live):
        app.include_router(module.router)
    app.mount("/static", page.static_files(), name="static")
    # added last = outermost: metrics see every answer, the body limit comes before the clock
    app.add_middleware(TimeLimit, timeout_s=settings.request_timeout_s)
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes, timeout_s=settings.body_timeout_s)
    app.add_middleware(Metrics, registry=registry)
    return app


def _openapi_with_settings(app: FastAPI, settings: Settings):
    """The OpenAPI document with the bounds this server's settings tighten: what the schema
    allows, the server accepts (the static ranges come from :mod:`excite.core.bounds`)."""
    generate = app.openapi

    def openapi() -> dict:
        if app.openapi_schema is not None:
            return app.openapi_schema
        doc = generate()
        models = doc["components"]["schemas"]

        def array(model: str, prop: str) -> dict:
            node = models[model]["properties"][prop]
            return next(n for n in [node, *node.get("anyOf", [])] if n.get("type") == "array")

        def tighten(node: dict, key: str, value: float) -> None:
            node[key] = min(node.get(key, value), value)

        s = settings
        tighten(models["ManeuverRequest"]["properties"]["duration_s"], "maximum", s.max_route_duration_s)
        tighten(models["ManeuverRequest"]["properties"]["time_budget_s"], "maximum", s.max_job_time_budget_s)
        for model, prop in (("RouteIn", "waypoints"), ("RouteIn", "poses"), ("ControlIn", "t_s")):
            tighten(array(model, prop), "maxItems", s.max_samples)
        tighten(array("BatchRequest", "routes"), "maxItems", s.max_batch_routes)
        return doc

    return openapi

