"""The one mapping from exceptions to RFC 9457 problems, and the one way each is sent.

:func:`of` maps every exception the service meets, the library's (:mod:`excite.errors`) and its
own (:mod:`api.errors`), to a :class:`~api.errors.Problem`; nothing in the library raises HTTP
exceptions. The problem then leaves as a response (:func:`response`, the app's handlers), from
ASGI middleware before the app (:func:`send`), as a /v1/live error frame
(:meth:`~api.errors.Problem.body`) or as a failed job's ``error``. A response never carries a
traceback: unexpected exceptions are logged server-side and answered with a bare 500.

This module imports no web framework at load time: the workers import it too.
"""

from __future__ import annotations

import errno
import logging
from typing import Any, Callable

from excite.errors import (BagError, EvaluationError, ExciteError, LimitError, RigError, RouteError,
                           SceneError, WorkerDied, WorkTimeout)

from .errors import TITLES, Overloaded, OverQuota, Problem, StoreError, Unsendable

log = logging.getLogger("excite.api")

PROBLEM_JSON = "application/problem+json"
INTERNAL = "The server failed to handle this request; the error is logged."
# the field a library error is reported against, by its class (the first that matches)
FIELDS: tuple[tuple[type[ExciteError], str], ...] = (
    (BagError, "bag"), (RouteError, "route"), (RigError, "rig"), (LimitError, "limits"),
    (EvaluationError, "evaluation"), (SceneError, "scene"))


def of(exc: BaseException, field: str | None = None, *, timeout_s: float | None = None,
       memory_mb: int | None = None) -> Problem:
    """The problem ``exc`` is answered with; ``field`` names the request field a library error is
    about (default: by its class). ``timeout_s`` and ``memory_mb`` are quoted by the 503 of a
    task past its deadline and the 413 of one out of memory."""
    if isinstance(exc, Problem):
        return exc
    if isinstance(exc, StoreError):  # logged by the store when the fault started
        return Problem(503, "the job store is unavailable; retry later (the fault is logged)",
                       type_="store-unavailable", headers={"Retry-After": "5"})
    if isinstance(exc, ExciteError):
        name = field or next((f for cls, f in FIELDS if isinstance(exc, cls)), "body")
        if isinstance(exc, RouteError):  # named by the request's field, never by a server path
            return Problem.at(name, exc.problem if exc.line is None else f"line {exc.line}: {exc.problem}")
        return Problem(422, str(exc), errors=[{"field": name, "message": str(exc)}])
    if isinstance(exc, Overloaded):
        return Problem(429, f"the service is busy: {exc.detail}; retry in {exc.retry_after_s} s",
                       type_="overloaded", headers={"Retry-After": str(exc.retry_after_s)})
    if isinstance(exc, OverQuota):
        return Problem(429, str(exc), type_="quota", headers={"Retry-After": "30"})
    if isinstance(exc, WorkTimeout):
        limit = f" of {timeout_s:g} s" if timeout_s is not None else ""
        return Problem(503, f"the request exceeded the time limit{limit}", type_="timeout",
                       headers={"Retry-After": "10"})
    if isinstance(exc, WorkerDied):
        return Problem(503, "a worker process died; retry the request", headers={"Retry-After": "1"})
    if isinstance(exc, MemoryError):
        limit = f" ({memory_mb} MiB)" if memory_mb else ""
        return Problem.at(field or "body", f"needs more memory than a worker may use{limit}; "
                                           "make it shorter or sparser", status=413)
    if isinstance(exc, (RecursionError, Unsendable)):
        return Problem.at(field or "body", "nested too deeply to process")
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        log.error("no space left on the server's disk: %s", exc)
        return Problem(503, "the server's disk is full; retry later (logged)", type_="disk-full",
                       headers={"Retry-After": "30"})
    log.error("unhandled error", exc_info=exc)
    return Problem(500, INTERNAL)


def response(problem: Problem, instance: str, close: bool = False) -> Any:
    """``problem`` as a response; ``close``: the connection is closed after it (a body left unread)."""
    from fastapi.responses import JSONResponse

    headers = {**(problem.headers or {}), **({"Connection": "close"} if close else {})}
    return JSONResponse(problem.body(instance), status_code=problem.status, media_type=PROBLEM_JSON,
                        headers=headers or None)


async def send(send_: Callable, problem: Problem, instance: str, close: bool = False) -> None:
    """``problem`` as the whole answer of an ASGI request (middleware that answers before the app)."""
    await response(problem, instance, close)({"type": "http"}, None, send_)


def field_name(loc: tuple[Any, ...] | list[Any]) -> str:
    """``("body", "route", "waypoints", 3)`` → ``"route.waypoints[3]"``."""
    from .schemas import RIG_TAGS

    out = ""
    for part in loc:
        if (part == "body" and not out) or part in RIG_TAGS:
            continue
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "body"


def validation(errors: list[dict[str, Any]]) -> Problem:
    """The 422 of a body that does not match its schema (pydantic's errors, every one named)."""
    named = []
    for e in errors:
        msg = e.get("msg", "invalid")
        if e.get("type") == "finite_number":
            msg = "must be a finite number (NaN and infinity are rejected)"
        named.append({"field": field_name(e.get("loc", ())), "message": msg})
    first = named[0] if named else {"field": "body", "message": "invalid request"}
    more = f" (and {len(named) - 1} more)" if len(named) > 1 else ""
    return Problem(422, f"{first['field']}: {first['message']}{more}", errors=named)


def _methods(request: Any) -> list[str]:
    """The methods the API documents for this request's path (all its routes)."""
    import re

    out: set[str] = set()
    for template, item in request.app.openapi().get("paths", {}).items():
        pattern = "^" + re.sub(r"\\{[^/]+?\\}", "[^/]+", re.escape(template)) + "$"
        if re.match(pattern, request.url.path):
            out |= {m.upper() for m in item if m in ("get", "post", "put", "patch", "delete")}
    return sorted(out)


def install(app: Any) -> None:
    """Every exception the app can raise answered with its problem."""
    from fastapi.exceptions import RequestValidationError
    from starlette.exceptions import HTTPException

    known = (Problem, ExciteError, Overloaded, OverQuota, WorkTimeout, WorkerDied, OSError)

    async def mapped(request: Any, exc: Exception) -> Any:
        if not isinstance(exc, known):
            log.exception("unhandled error on %s %s", request.method, request.url.path, exc_info=exc)
            return response(Problem(500, INTERNAL), request.url.path)
        return response(of(exc), request.url.path)

    async def invalid(request: Any, exc: RequestValidationError) -> Any:
        return response(validation(exc.errors()), request.url.path)

    async def http(request: Any, exc: HTTPException) -> Any:
        detail = exc.detail if isinstance(exc.detail, str) else TITLES.get(exc.status_code, "Error")
        headers = dict(getattr(exc, "headers", None) or {})
        if exc.status_code == 405:  # every method of the path, not only the first route's
            own = {m.strip() for m in headers.get("Allow", "").split(",") if m.strip()}
            headers["Allow"] = ", ".join(sorted(own | set(_methods(request))))
        return response(Problem(exc.status_code, detail, headers=headers or None), request.url.path)

    app.add_exception_handler(RequestValidationError, invalid)
    app.add_exception_handler(HTTPException, http)
    app.add_exception_handler(Exception, mapped)
    for cls in known:
        app.add_exception_handler(cls, mapped)
