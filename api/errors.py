"""The exception tree of the service, every class of it in this one module.

    Exception
    ├── Problem               an error answered with a problem document: raised by routers and
    │                         by tasks in workers (it pickles), sent as a /v1/live error frame
    ├── Refusal               ends a /v1/live session with a problem frame and a close code
    ├── Overloaded            the work cannot be done by its deadline: refused now (429, Retry-After)
    ├── OverQuota             a key's quota of jobs or storage would be exceeded (429)
    ├── Unsendable            a task's arguments cannot be sent to a worker
    (a task past its deadline, a worker that died: excite.errors.WorkTimeout, WorkerDied)
    └── excite.errors.ExciteError
        ├── StoreError        the job database cannot be opened or used (names it and why:
        │                     full, read-only, corrupt, unreachable); answered 503
        ├── KeysError         the API keys file cannot be read or is invalid (names the entry)
        └── Exposed           the server would serve without keys on a non-loopback address

:func:`api.problems.of` maps each of them, and excite's own errors, to its problem.
"""

from __future__ import annotations

from typing import Any

from excite.errors import ExciteError

TITLES = {400: "Bad request", 401: "Unauthorized", 403: "Forbidden", 404: "Not found",
          405: "Method not allowed", 406: "Not acceptable", 408: "Request timeout", 409: "Conflict",
          413: "Content too large", 415: "Unsupported media type", 421: "Misdirected request",
          422: "Unprocessable content", 429: "Too many requests", 500: "Internal server error",
          503: "Service unavailable"}
TYPES = {401: "unauthorized", 403: "forbidden", 404: "not-found", 408: "timeout", 409: "conflict",
         413: "too-large", 422: "validation", 429: "too-many-requests", 500: "internal",
         503: "unavailable"}
TYPE_BASE = "https://excite.dev/problems/"
# every body is bounded, whatever the input it talks about (a bag of 50 000 frames, a rig of
# 20 000 topics): a long detail or message is cut, and at most MAX_ERRORS are listed
MAX_DETAIL_CHARS = 2000
MAX_MESSAGE_CHARS = 500
MAX_ERRORS = 20


def cut(text: str, limit: int) -> str:
    """``text`` of at most ``limit`` characters, saying how much was left out."""
    if len(text) <= limit:
        return text
    note = f" … ({len(text) - limit + 40:,} characters more)"
    return text[:limit - len(note)] + note


class Problem(Exception):
    """An RFC 9457 problem: ``status``, ``detail``, the ``errors`` naming the offending fields,
    the response ``headers`` (``Retry-After``). :meth:`body` is the document."""

    def __init__(self, status: int, detail: str, *, type_: str | None = None,
                 title: str | None = None, errors: list[dict[str, Any]] | None = None,
                 headers: dict[str, str] | None = None):
        super().__init__(status, detail)
        self.status, self.detail = status, detail
        self.type_ = type_ or TYPES.get(status, "http-error")
        self.title = title or TITLES.get(status, "Error")
        self.errors, self.headers = errors, headers

    @classmethod
    def at(cls, field: str, message: str, status: int = 422, **kw: Any) -> "Problem":
        """The problem of one field: ``"field: message"``, with the field named in ``errors``."""
        return cls(status, f"{field}: {message}", errors=[{"field": field, "message": message}], **kw)

    def body(self, instance: str = "") -> dict[str, Any]:
        """The problem document, within the bounds above."""
        out: dict[str, Any] = {"type": TYPE_BASE + self.type_, "title": self.title, "status": self.status,
                               "detail": cut(self.detail, MAX_DETAIL_CHARS), "instance": instance}
        if self.errors is not None:
            out["errors"] = [{"field": cut(str(e.get("field", "")), 200),
                              "message": cut(str(e.get("message", "")), MAX_MESSAGE_CHARS)}
                             for e in self.errors[:MAX_ERRORS]]
            if len(self.errors) > MAX_ERRORS:
                out["errors"].append({"field": "", "message": f"… and {len(self.errors) - MAX_ERRORS} more errors"})
        return out


class Refusal(Exception):
    """Ends a /v1/live session: its problem as an error frame, then the WebSocket close code
    (by the status unless given: 1009 too large, 1011 a server failure, 1008 otherwise)."""

    CLOSE = {413: 1009, 500: 1011, 503: 1011}

    def __init__(self, problem: Problem, close_code: int | None = None):
        super().__init__(problem.detail)
        self.problem, self.close_code = problem, close_code or self.CLOSE.get(problem.status, 1008)


class Overloaded(Exception):
    """The work cannot be done by its deadline (the workers' queue, or this key's share of them,
    holds more than that): refused now, retry after ``retry_after_s``."""

    def __init__(self, detail: str, retry_after_s: int):
        super().__init__(detail)
        self.detail, self.retry_after_s = detail, retry_after_s


class OverQuota(Exception):
    """A key's quota of jobs or of storage would be exceeded by this job (429)."""


class Unsendable(Exception):
    """The task's arguments cannot be sent to a worker (e.g. nested too deeply to pickle)."""


class StoreError(ExciteError):
    """The job database cannot be opened or used (the message names it and why)."""


class KeysError(ExciteError):
    """The API keys file cannot be read or is not valid (the message names file and entry)."""


class Exposed(ExciteError):
    """The server would serve without API keys on an address others can reach."""
