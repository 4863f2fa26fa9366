"""RFC 9457 problem details: every error response of the service is one of these.

Domain errors are mapped to HTTP statuses here, in one place; nothing in the library raises
HTTP exceptions. A response never carries a traceback: unexpected exceptions are logged
server-side and answered with a bare 500.
"""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from excite.errors import EvaluationError, ExciteError, LimitError, RigError, RouteError
from .errors import TITLES, ProblemError, StoreError, default_type

log = logging.getLogger("excite.api")

PROBLEM_JSON = "application/problem+json"
TYPE_BASE = "https://excite.dev/problems/"
# every error body is bounded, whatever the input it talks about (a bag of 50 000 frames, a
# rig of 20 000 topics): a long detail or message is cut, and at most MAX_ERRORS are listed
MAX_DETAIL_CHARS = 2000
MAX_MESSAGE_CHARS = 500
MAX_ERRORS = 20


def cut(text: str, limit: int) -> str:
    """``text`` of at most ``limit`` characters, saying how much was left out."""
    if len(text) <= limit:
        return text
    note = f" … ({len(text) - limit + 40:,} characters more)"
    return text[:limit - len(note)] + note


def capped(body: dict[str, Any]) -> dict[str, Any]:
    """A problem document within the bounds above."""
    out = dict(body)
    if isinstance(out.get("detail"), str):
        out["detail"] = cut(out["detail"], MAX_DETAIL_CHARS)
    errors = out.get("errors")
    if isinstance(errors, list):
        kept = [{**e, "field": cut(str(e.get("field", "")), 200),
                 "message": cut(str(e.get("message", "")), MAX_MESSAGE_CHARS)} for e in errors[:MAX_ERRORS]]
        if len(errors) > MAX_ERRORS:
            kept.append({"field": "", "message": f"… and {len(errors) - MAX_ERRORS} more errors"})
        out["errors"] = kept
    return out


def problem(status: int, detail: str, *, instance: str = "", type_: str | None = None,
            title: str | None = None, errors: list[dict[str, Any]] | None = None,
            headers: dict[str, str] | None = None) -> JSONResponse:
    """A problem+json response."""
    body: dict[str, Any] = {"type": TYPE_BASE + (type_ or default_type(status)),
                            "title": title or TITLES.get(status, "Error"), "status": status,
                            "detail": detail, "instance": instance}
    if errors is not None:
        body["errors"] = errors
    return JSONResponse(capped(body), status_code=status, media_type=PROBLEM_JSON, headers=headers)


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


def excite_problem(exc: ExciteError, field: str | None = None) -> tuple[int, str, list[dict[str, Any]]]:
    """(status, detail, errors) of a domain error: every ExciteError is the client's input."""
    kind = {RouteError: "route", RigError: "rig", LimitError: "limits",
            EvaluationError: "evaluation"}
    default = next((v for k, v in kind.items() if isinstance(exc, k)), "body")
    name = field or default
    return 422, str(exc), [{"field": name, "message": str(exc)}]


def _methods(request: Request) -> list[str]:
    """The methods the API documents for this request's path (all its routes, not only the
    first one the router tried)."""
    import re

    out: set[str] = set()
    for template, item in request.app.openapi().get("paths", {}).items():
        pattern = "^" + re.sub(r"\\{[^/]+?\\}", "[^/]+", re.escape(template)) + "$"
        if re.match(pattern, request.url.path):
            out |= {m.upper() for m in item if m in ("get", "post", "put", "patch", "delete")}
    return sorted(out)


def install(app: FastAPI) -> None:
    """Map every exception the app can raise to a problem document."""

    @app.exception_handler(ProblemError)
    async def _problem(request: Request, exc: ProblemError) -> JSONResponse:
        return problem(exc.status, exc.detail, instance=request.url.path, type_=exc.type_,
                       title=exc.title, errors=exc.errors, headers=exc.headers)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = []
        for e in exc.errors():
            msg = e.get("msg", "invalid")
            if e.get("type") == "finite_number":
                msg = "must be a finite number (NaN and infinity are rejected)"
            errors.append({"field": field_name(e.get("loc", ())), "message": msg})
        first = errors[0] if errors else {"field": "body", "message": "invalid request"}
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        return problem(422, f"{first['field']}: {first['message']}{more}",
                       instance=request.url.path, errors=errors)

    @app.exception_handler(StoreError)
    async def _store(request: Request, exc: StoreError) -> JSONResponse:
        log.error("job store fault on %s %s: %s", request.method, request.url.path, exc)
        return problem(503, "the job store is unavailable; retry later (the fault is logged)",
                       instance=request.url.path, type_="store-unavailable", headers={"Retry-After": "5"})

    @app.exception_handler(OSError)
    async def _os(request: Request, exc: OSError) -> JSONResponse:
        import errno

        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            log.error("%s %s: no space left on the server's disk (%s)", request.method, request.url.path, exc)
            return problem(503, "the server's disk is full; retry later (logged)", instance=request.url.path,
                           type_="disk-full", headers={"Retry-After": "30"})
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem(500, "The server failed to handle this request; the error is logged.",
                       instance=request.url.path)

    @app.exception_handler(ExciteError)
    async def _domain(request: Request, exc: ExciteError) -> JSONResponse:
        status, detail, errors = excite_problem(exc)
        return problem(status, detail, instance=request.url.path, errors=errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else TITLES.get(exc.status_code, "Error")
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:  # every method of the path, not only the first route's
            headers = {**(headers or {}), "Allow": ", ".join(_methods(request))}
        return problem(exc.status_code, detail, instance=request.url.path, headers=headers)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem(500, "The server failed to handle this request; the error is logged.",
                       instance=request.url.path)
