"""What the routes need, carried by dependencies: settings, the job store and runner, the scoring
pool, the API keys and request rates, the metrics registry; and the request's own deadline.

A route that needs work done calls :meth:`Context.run` (or :meth:`Context.run_all`); every failure
comes back as an exception that :func:`api.problems.of` maps.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Any, Callable

from fastapi import Depends, Request
from prometheus_client import CollectorRegistry, Gauge
from starlette.requests import HTTPConnection

from excite.errors import WorkTimeout

from . import problems
from .auth import KeyRing, Principal, RateLimiter
from .cluster import ClusterScoring
from .jobs import JobRunner
from .middleware import Deadline
from .pool import WorkerPool
from .scoring import Bounds
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
    store_up: Gauge
    cluster: ClusterScoring | None = None  # batch routes go to the Dask cluster when configured
    keys: KeyRing | None = None  # None: an open server
    rates: RateLimiter = field(default_factory=RateLimiter)
    live_sessions: dict[str, int] = field(default_factory=dict)  # key id → sessions streaming here

    @property
    def bounds(self) -> Bounds:
        s = self.settings
        return Bounds(s.max_samples, s.max_route_duration_s, s.max_route_length_m)

    def storage_bytes(self, key_id: str) -> int:
        """The key's storage quota [bytes] (an open server: the default)."""
        who = self.keys.by_id(key_id) if self.keys is not None else None
        mb = who.limits.storage_mb if who is not None and who.limits is not None else self.settings.quota_storage_mb
        return mb * 2**20

    def run_all(self, request: Request, who: Principal, fn: Callable[..., Any], calls: list[tuple],
                sizes: list[float] | None = None, cluster: bool = False) -> list[Any]:
        """``fn(*args)`` for each ``args`` of ``calls`` in scoring workers (on the Dask cluster
        with ``cluster`` when one is configured), all admitted or none, by the request's deadline."""
        until = deadline(request).work_until()
        if cluster and self.cluster is not None:
            futures = [self.cluster.submit(fn, *args, deadline=until) for args in calls]
        else:
            futures = self.pool.submit(fn, calls, until, key=who.key_id, sizes=sizes)
        try:
            return [f.result() for f in futures]
        except BaseException as exc:
            for f in futures:
                f.cancel()
            if isinstance(exc, (WorkTimeout, MemoryError)):
                raise problems.of(exc, timeout_s=self.settings.request_timeout_s,
                                  memory_mb=self.settings.worker_memory_mb) from None
            raise

    def run(self, request: Request, who: Principal, fn: Callable[..., Any], *args: Any, size: float = 1.0) -> Any:
        (out,) = self.run_all(request, who, fn, [args], [size])
        return out


def deadline(request: Request) -> Deadline:
    """The request's :class:`~api.middleware.Deadline` (set by :class:`~api.middleware.TimeLimit`)."""
    return request.scope["state"]["deadline"]


def get_context(conn: HTTPConnection) -> Context:  # a request's or a WebSocket's
    return conn.app.state.ctx


Ctx = Annotated[Context, Depends(get_context)]
