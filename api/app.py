"""The app factory: settings → a FastAPI app with its middleware, routers, store and workers.

Start-up opens the job store (SQLite or PostgreSQL, migrated), reads the API keys, re-queues
the jobs of servers that are gone, starts the job dispatcher and the scoring processes;
shutdown stops them and puts this server's running jobs back in the queue. Adding a route or a
job kind: docs/guides/service.md.
"""

from __future__ import annotations

import logging
from contextlib import asynccontextmanager
from typing import AsyncIterator

import anyio
from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from prometheus_client import CollectorRegistry, Gauge

from excite.core import processes

from . import auth, problems
from .auth import Authenticate, Quota, load_keys
from .cluster import ClusterScoring
from .context import Context
from .jobs import JobRunner
from .middleware import BodyLimit, Guard, Metrics, TimeLimit
from .pool import WorkerPool
from .routers import batch, health, jobs, live, maneuvers, page, rigs, scenes, score
from .scoring import warm
from .settings import Settings
from .store import JobStore

log = logging.getLogger("excite.api")

ROUTERS = (score, batch, scenes, maneuvers, jobs, rigs, health, page, live)
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
    store = JobStore(settings.database_url or settings.db_path)
    keys = None
    if settings.api_keys_file is not None:
        defaults = Quota(**{f: getattr(settings, f"quota_{f}") for f in Quota.model_fields})  # EXCITE_QUOTA_*
        keys = load_keys(settings.api_keys_file, defaults)
    registry = CollectorRegistry()
    ctx = Context(
        settings=settings, store=store,
        runner=JobRunner(store, settings, job_function),
        cluster=ClusterScoring(settings.dask_scheduler) if settings.dask_scheduler else None,
        pool=WorkerPool(settings.score_workers, settings.worker_memory_mb, settings.worker_recycle_mb,
                        warm=warm, max_queued=settings.max_queued_tasks,
                        share=settings.score_share if keys is not None else 1.0),
        registry=registry,
        jobs_gauge=Gauge("excite_jobs", "Jobs in the store by status", ["status"], registry=registry),
        store_up=Gauge("excite_store_up", "Whether the job store answered the last scrape", registry=registry),
        keys=keys)
    ctx.runner.storage_bytes = ctx.storage_bytes
    secret = store.secret("ticket")

    def redeem(ticket: str) -> str | None:
        claims = auth.ticket_claims(secret, ticket)
        if claims is None or not store.redeem(claims[2], claims[1]):
            return None
        return claims[0]

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        ctx.runner.start()
        await anyio.to_thread.run_sync(ctx.pool.start)
        log.info("excite service ready (jobs in %s; %s)", store.describe(),
                 f"{len(keys.entries)} API keys" if keys else "open: no API keys")
        try:
            yield
        finally:
            ctx.runner.stop()
            ctx.pool.close()
            processes.stop_all()  # the live sessions' processes
            if ctx.cluster is not None:
                ctx.cluster.close()

    app = FastAPI(title="excite", version="1", description=DESCRIPTION, lifespan=lifespan,
                  docs_url=None, redoc_url=None, openapi_url=None)
    app.state.ctx = ctx
    app.state.ticket_secret = secret
    app.openapi = _openapi_with_settings(app, settings, open_server=keys is None)
    problems.install(app)
    page.add_docs(app, "public" if keys is None else settings.docs)  # EXCITE_DOCS
    for module in ROUTERS:
        app.include_router(module.router)
    health.add_metrics(app, "public" if keys is None else settings.metrics)
    app.mount("/static", StaticFiles(directory=page.STATIC_DIR), name="static")
    # added last = outermost: the guard (hosts, browser safety, security headers, the last word
    # on errors), then the key from the headers (before any body is read), metrics, the body limit,
    # the clock
    app.add_middleware(TimeLimit, timeout_s=settings.request_timeout_s)
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes, timeout_s=settings.body_timeout_s)
    app.add_middleware(Metrics, registry=registry)
    app.add_middleware(Authenticate, ring=keys, rates=ctx.rates, redeem=redeem)
    app.add_middleware(Guard, hosts=settings.hosts(open_server=keys is None), origins=settings.origins)
    return app


def _openapi_with_settings(app: FastAPI, settings: Settings, open_server: bool):
    """The OpenAPI document with the bounds this server's settings tighten: what the schema
    allows, the server accepts (the static ranges come from :mod:`excite.core.bounds`). An open
    server asks for no credentials, so its document declares none."""
    from fastapi.openapi.utils import get_openapi

    def openapi() -> dict:
        if app.openapi_schema is not None:
            return app.openapi_schema
        doc = get_openapi(title=app.title, version=app.version, description=app.description,
                          routes=app.routes)
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
        if open_server:  # it asks for no credentials
            doc["components"].pop("securitySchemes", None)
            for op in (op for item in doc["paths"].values() for op in item.values() if isinstance(op, dict)):
                op.pop("security", None)
        app.openapi_schema = doc
        return doc

    return openapi

