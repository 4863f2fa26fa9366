"""What the routers need, carried by dependencies: settings, the job store and runner, the
scoring pool, the API keys and request rates, and the metrics registry."""

from __future__ import annotations

import concurrent.futures as cf
import time
from dataclasses import dataclass, field
from typing import Annotated, Any, Callable

from fastapi import Depends, Request
from prometheus_client import CollectorRegistry, Gauge

from .auth import KeyRing, RateLimiter
from .cluster import ClusterScoring
from .jobs import JobRunner
from .errors import Overloaded, ProblemError, Unsendable, WorkerDied, WorkTimeout
from .pool import WorkerPool
from .scoring import Bounds, plot_task, score_task
from .settings import Settings
from .store import JobStore


@dataclass
class Context:
    settings: Settings
    store: JobStore
    runner: JobRunner
    pool: WorkerPool
    registry: CollectorRegistry
    jobs_gauge: Gauge
    started_at: float
    store_up: Gauge
    cluster: ClusterScoring | None = None  # batch routes go to the Dask cluster when configured
    keys: KeyRing | None = None  # None: an open server
    rates: RateLimiter = field(default_factory=RateLimiter)
    live_sessions: dict[str, int] = field(default_factory=dict)  # key id → sessions streaming here

    @property
    def bounds(self) -> Bounds:
        s = self.settings
        return Bounds(s.max_samples, s.max_route_duration_s, s.max_route_length_m)

    def submit(self, fn: Callable[..., Any], calls: list[tuple], deadline: float) -> list[cf.Future]:
        """``fn(*args)`` for each ``args`` in a scoring worker, or a 429 with Retry-After when
        the workers are too busy to finish them by ``deadline`` (honest back-pressure: the
        client learns at once, instead of a 503 after the whole time limit)."""
        try:
            return self.pool.submit_all(fn, calls, deadline)
        except Overloaded as exc:
            raise ProblemError(429, f"the service is busy: {exc.detail}; retry in "
                                    f"{exc.retry_after_s} s", type_="overloaded",
                               headers={"Retry-After": str(exc.retry_after_s)}) from None

    def submit_scores(self, routes: list[tuple[dict[str, Any], str]], rig: Any, segments: int,
                      limits: dict[str, float] | None, deadline: float,
                      track_points: int = 0) -> list[cf.Future]:
        """Score each ``(route, field)`` (all admitted or none)."""
        return self.submit(score_task, [(route, rig, segments, limits, self.bounds, field, "rig",
                                         track_points) for route, field in routes], deadline)

    def submit_batch_scores(self, routes: list[tuple[dict[str, Any], str]], rig: Any, segments: int,
                            limits: dict[str, float] | None, deadline: float) -> list[cf.Future]:
        """Batch routes: on the Dask cluster when one is configured, else as :meth:`submit_scores`."""
        if self.cluster is None:
            return self.submit_scores(routes, rig, segments, limits, deadline)
        return [self.cluster.submit(score_task, route, rig, segments, limits, self.bounds, field, "rig", 0,
                                    deadline=deadline) for route, field in routes]

    def submit_plot(self, route: dict[str, Any], rig: Any, segments: int,
                    limits: dict[str, float] | None, parameter: str | None, deadline: float) -> cf.Future:
        (fut,) = self.submit(plot_task, [(route, rig, segments, limits, self.bounds, parameter)], deadline)
        return fut

    def wait(self, futures: list[cf.Future]) -> list[dict[str, Any]]:
        """The results of ``futures``; 503 when the deadline they were submitted with passed
        (their workers were killed then: the work ends with the request)."""
        out = []
        for f in futures:
            try:
                out.append(f.result())
            except WorkTimeout:
                for g in futures:
                    g.cancel()
                raise ProblemError(503, "the request exceeded the time limit of "
                                        f"{self.settings.request_timeout_s:g} s",
                                   type_="timeout", headers={"Retry-After": "10"}) from None
            except Unsendable:
                raise ProblemError(422, "the request is nested too deeply to process",
                                   errors=[{"field": "body", "message": "nested too deeply"}]) from None
            except WorkerDied:
                raise ProblemError(503, "a scoring worker died; retry the request",
                                   type_="unavailable", headers={"Retry-After": "1"}) from None
            except MemoryError:
                raise ProblemError(413, "the route needs more memory than a worker may use "
                                        f"({self.settings.worker_memory_mb} MiB)") from None
        return out

    def deadline(self) -> float:
        # a little under the middleware's limit, so the router answers first
        return time.monotonic() + 0.95 * self.settings.request_timeout_s


def get_context(request: Request) -> Context:
    return request.app.state.ctx


Ctx = Annotated[Context, Depends(get_context)]


def raise_problem(result: dict[str, Any]) -> None:
    """Raise the problem a score task returned."""
    status = result["status"]
    if status >= 500:
        raise ProblemError(500, "The server failed to score this route; the error is logged.")
    raise ProblemError(status, result["detail"], errors=result["errors"])
