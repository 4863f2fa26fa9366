"""Problem responses every operation documents."""

from __future__ import annotations

from typing import Any

from ..problems import PROBLEM_JSON
from ..schemas import Problem


def problems(*statuses: int) -> dict[int | str, dict[str, Any]]:
    text = {400: "The body cannot be parsed (not UTF-8 JSON)", 404: "Unknown resource",
            401: "No API key, or not one of this server's (servers with keys only)",
            403: "The key lacks the scope, or a browser request from another site",
            408: "The body did not arrive in time (slow client)", 409: "Conflict with the resource's state",
            413: "Body, route or batch too large (the bound is in the detail)",
            422: "Invalid input (the offending field is named in `errors`)",
            429: "Over a quota of the key, or the workers are too busy to finish this in time: retry "
                 "after `Retry-After` seconds",
            500: "Internal error (no details; logged server-side)",
            421: "The Host is not one this server answers to (EXCITE_ALLOWED_HOSTS)",
            503: "Time limit exceeded or not ready"}
    return {s: {"model": Problem, "description": text[s], "content": {PROBLEM_JSON: {}}}
            for s in statuses}


AUTH = problems(401, 403, 429)  # every operation of a server with API keys
BODY = problems(400, 401, 403, 408, 413, 421, 422, 429, 500, 503)
