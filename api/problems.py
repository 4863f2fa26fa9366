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

log = logging.getLogger("excite.api")

PROBLEM_JSON = "application/problem+json"
TYPE_BASE = "https://excite.dev/problems/"

_TITLES = {400: "Bad request", 404: "Not found", 405: "Method not allowed",
           406: "Not acceptable", 408: "Request timeout", 409: "Conflict", 413: "Content too large",
           415: "Unsupported media type", 422: "Unprocessable content", 429: "Too many requests",
           500: "Internal server error", 503: "Service unavailable"}


class ProblemError(Exception):
    """An error the service answers with a problem document (raised by routers)."""

    def __init__(self, status: int, detail: str, *, type_: str | None = None,
                 title: str | None = None, errors: list[dict[str, Any]] | None = None,
                 headers: dict[str, str] | None = None):
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.type_ = type_ or _default_type(status)
        self.title = title or _TITLES.get(status, "Error")
        self.errors = errors
        self.headers = headers


def _default_type(status: int) -> str:
    return {404: "not-found", 409: "conflict", 413: "too-large", 422: "validation",
            500: "internal", 503: "unavailable"}.get(status, "http-error")


def problem(status: int, detail: str, *, instance: str = "", type_: str | None = None,
            title: str | None = None, errors: list[dict[str, Any]] | None = None,
            headers: dict[str, str] | None = None) -> JSONResponse:
    """A problem+json response."""
    body: dict[str, Any] = {"type": TYPE_BASE + (type_ or _default_type(status)),
                            "title": title or _TITLES.get(status, "Error"), "status": status,
                            "detail": detail, "instance": instance}
    if errors is not None:
        body["errors"] = errors
    return JSONResponse(body, status_code=status, media_type=PROBLEM_JSON, headers=headers)


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

    @app.exception_handler(ExciteError)
    async def _domain(request: Request, exc: ExciteError) -> JSONResponse:
        status, detail, errors = excite_problem(exc)
        return problem(status, detail, instance=request.url.path, errors=errors)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else _TITLES.get(exc.status_code, "Error")
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:  # every method of the path, not only the first route's
            headers = {**(headers or {}), "Allow": ", ".join(_methods(request))}
        return problem(exc.status_code, detail, instance=request.url.path, headers=headers)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        log.exception("unhandled error on %s %s", request.method, request.url.path)
        return problem(500, "The server failed to handle this request; the error is logged.",
                       instance=request.url.path)
