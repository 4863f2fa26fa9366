"""The exception tree of the service, every class of it in this one module.

    Exception
    ├── ProblemError          an error answered with a problem document (raised by routers)
    ├── Rejected              input a scoring request is refused for: (status, field, message)
    ├── Overloaded            every worker busy: refused now with a Retry-After (503/429)
    ├── WorkTimeout           a task did not finish by its deadline (its worker was killed)
    ├── WorkerDied            a worker ended while running a task
    ├── Unsendable            a task's arguments cannot be sent to a worker
    ├── Refused               a /v1/live message or session refused: closes the socket with a problem frame
    └── excite.errors.ExciteError
        ├── StoreError        the job database cannot be opened or used (names it and why:
        │                     full, read-only, corrupt, unreachable); answered 503
        ├── KeysError         the API keys file cannot be read or is invalid (names the entry)
        └── Exposed           the server would serve without keys on a non-loopback address

:mod:`api.problems` maps each to its HTTP status and problem+json body in one place; excite's own
errors (:mod:`excite.errors`) map to 4xx there too. Anything else is a 500 without a traceback
in the body (and with one in the log).
"""

from __future__ import annotations

from typing import Any

from excite.errors import ExciteError

TITLES = {400: "Bad request", 401: "Unauthorized", 403: "Forbidden", 404: "Not found",
          405: "Method not allowed", 406: "Not acceptable", 408: "Request timeout", 409: "Conflict",
          413: "Content too large", 415: "Unsupported media type", 422: "Unprocessable content",
          429: "Too many requests", 500: "Internal server error", 503: "Service unavailable"}


def default_type(status: int) -> str:
    return {401: "unauthorized", 403: "forbidden", 404: "not-found", 409: "conflict", 413: "too-large", 422: "validation",
            500: "internal", 503: "unavailable"}.get(status, "http-error")


class ProblemError(Exception):
    """An error the service answers with a problem document (raised by routers)."""

    def __init__(self, status: int, detail: str, *, type_: str | None = None,
                 title: str | None = None, errors: list[dict[str, Any]] | None = None,
                 headers: dict[str, str] | None = None):
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.type_ = type_ or default_type(status)
        self.title = title or TITLES.get(status, "Error")
        self.errors = errors
        self.headers = headers


class Rejected(Exception):
    """Input the service refuses: (status, field, message)."""

    def __init__(self, status: int, field: str, message: str):
        super().__init__(message)
        self.status, self.field, self.message = status, field, message


class Overloaded(Exception):
    """Every worker is busy and the task would wait past its deadline or over the queue bound:
    refused now (the client retries after ``retry_after_s``) instead of timing out later."""

    def __init__(self, detail: str, retry_after_s: int):
        super().__init__(detail)
        self.detail, self.retry_after_s = detail, retry_after_s


class WorkTimeout(Exception):
    """The task did not finish by its deadline (its worker, if it had one, was killed)."""


class WorkerDied(Exception):
    """The worker ended while running the task (e.g. killed by the system)."""


class Unsendable(Exception):
    """The task's arguments cannot be sent to a worker (e.g. nested too deeply to pickle)."""


class Refused(Exception):
    def __init__(self, status: int, field: str, message: str, close_code: int = 1008):
        super().__init__(message)
        self.status, self.field, self.message, self.close_code = status, field, message, close_code


class StoreError(ExciteError):
    """The job database cannot be opened or used (the message names it and why)."""


class KeysError(ExciteError):
    """The API keys file cannot be read or is not valid (the message names file and entry)."""


class Exposed(ExciteError):
    """The server would serve without API keys on an address others can reach."""
