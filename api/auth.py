"""Who may do what: API keys with scopes and an owner, checked by FastAPI's security
dependencies, and each key's quotas.

The operator lists the keys in a file (``EXCITE_API_KEYS_FILE``, YAML or JSON) holding only
their SHA-256 hashes (``python -m api.keys new`` makes a key and prints its entry)::

    keys:
      - id: ci-gate          # names the key in logs, metrics and job records
        owner: calibration   # who holds it
        scopes: [score]      # score, plan, admin
        sha256: 9f2c…        # of the secret; the secret itself is never stored
        quota: {jobs: 50, live_sessions: 2, rate_per_s: 5, burst: 10}   # optional overrides

A client sends its key as ``X-API-Key: <key>`` or ``Authorization: Bearer <key>``
(:class:`fastapi.security.APIKeyHeader`, :class:`fastapi.security.HTTPBearer`); a browser's
WebSocket, which cannot set headers, sends a short-lived ticket as ``?ticket=`` (from
``POST /v1/live/tickets``; :class:`fastapi.security.APIKeyQuery`), signed with a secret every
replica derives from the same keys file.

Scopes: ``score`` (score, plot, batch, live), ``plan`` (maneuver jobs: create, read, cancel,
download), ``admin`` (everything, every key's jobs, metrics). A job belongs to the key that
made it: another key gets 404 for it, ``admin`` sees it. No key or an unknown one: 401; a key
without the scope: 403; over its request rate: 429 with ``Retry-After``.

Without a keys file the server is **open**: everyone is admin and no quota applies (the
embedded default: one user on their own machine). :func:`check_exposure` refuses to serve open
on an address other than loopback unless ``EXCITE_OPEN=true`` says so.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import ipaddress
import json
import secrets
import socket
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

from fastapi import Depends, Security
from fastapi.security import APIKeyHeader, APIKeyQuery, HTTPAuthorizationCredentials, HTTPBearer, SecurityScopes
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from starlette.requests import HTTPConnection

from .errors import Exposed, KeysError, ProblemError
from .store import OPEN_KEY

SCOPES = ("score", "plan", "admin")
KEY_PREFIX = "exk_"
TICKET_TTL_S = 60.0

key_header = APIKeyHeader(name="X-API-Key", auto_error=False, scheme_name="APIKey",
                          description="An API key the operator issued (see README, HTTP service).")
bearer = HTTPBearer(auto_error=False, scheme_name="Bearer", description="The same API key as a bearer token.")
ticket_query = APIKeyQuery(name="ticket", auto_error=False, scheme_name="LiveTicket",
                           description="/v1/live only: a ticket from POST /v1/live/tickets (60 s).")


class Quota(BaseModel):
    """A key's limits (any left out: the server's ``EXCITE_QUOTA_*`` settings)."""

    model_config = ConfigDict(extra="forbid")
    jobs: int | None = Field(None, ge=0, le=100_000, description="Queued and running jobs at once.")
    live_sessions: int | None = Field(None, ge=0, le=1000, description="/v1/live sessions at once.")
    rate_per_s: float | None = Field(None, gt=0, le=100_000, description="Requests per second on average.")
    burst: int | None = Field(None, ge=1, le=100_000, description="Requests at once above the rate.")


class KeyEntry(BaseModel):
    model_config = ConfigDict(extra="forbid")
    id: str = Field(pattern=r"^[A-Za-z0-9_.-]{1,64}$")
    owner: str = Field(min_length=1, max_length=200)
    scopes: list[str] = Field(min_length=1)
    sha256: str = Field(pattern=r"^[0-9a-f]{64}$")
    quota: Quota = Quota()


class KeysFile(BaseModel):
    model_config = ConfigDict(extra="forbid")
    keys: list[KeyEntry] = Field(min_length=1)


@dataclass(frozen=True)
class Limits:
    jobs: int
    live_sessions: int
    rate_per_s: float
    burst: int


@dataclass(frozen=True)
class Principal:
    """Who a request is: the key's id (jobs belong to it), its owner, scopes and limits
    (``limits`` None: no quota, an open server)."""

    key_id: str
    owner: str
    scopes: frozenset[str]
    limits: Limits | None = None

    @property
    def admin(self) -> bool:
        return "admin" in self.scopes

    def allows(self, scope: str) -> bool:
        return self.admin or scope in self.scopes

    @property
    def job_filter(self) -> str | None:
        """The key whose jobs this principal sees (None: every job)."""
        return None if self.admin else self.key_id


OPEN = Principal(OPEN_KEY, "", frozenset(SCOPES))


def hash_key(secret: str) -> str:
    """SHA-256 of a key, hex: keys are 256-bit random tokens, so a fast hash is enough (no
    dictionary to guess from) and costs nothing per request."""
    return hashlib.sha256(secret.encode("utf-8")).hexdigest()


def new_key() -> str:
    return KEY_PREFIX + secrets.token_urlsafe(32)


@dataclass
class KeyRing:
    """The keys of one file, by hash; ``secret`` signs live tickets (the same on every replica
    that reads the same file)."""

    entries: dict[str, KeyEntry]
    secret: bytes
    defaults: Limits

    def lookup(self, key: str) -> Principal | None:
        entry = self.entries.get(hash_key(key))
        return None if entry is None else self.principal(entry)

    def by_id(self, key_id: str) -> Principal | None:
        entry = next((e for e in self.entries.values() if e.id == key_id), None)
        return None if entry is None else self.principal(entry)

    def principal(self, entry: KeyEntry) -> Principal:
        q, d = entry.quota, self.defaults
        limits = Limits(d.jobs if q.jobs is None else q.jobs,
                        d.live_sessions if q.live_sessions is None else q.live_sessions,
                        d.rate_per_s if q.rate_per_s is None else q.rate_per_s,
                        d.burst if q.burst is None else q.burst)
        return Principal(entry.id, entry.owner, frozenset(entry.scopes), limits)

    # live tickets: key id, expiry, HMAC of both
    def ticket(self, principal: Principal, ttl_s: float = TICKET_TTL_S) -> str:
        body = f"{principal.key_id}.{int(time.time() + ttl_s)}"
        sig = hmac.new(self.secret, body.encode(), hashlib.sha256).digest()
        return body + "." + base64.urlsafe_b64encode(sig).decode().rstrip("=")

    def redeem(self, ticket: str) -> Principal | None:
        try:
            key_id, expiry, sig = ticket.rsplit(".", 2)
            good = base64.urlsafe_b64encode(hmac.new(self.secret, f"{key_id}.{expiry}".encode(),
                                                     hashlib.sha256).digest()).decode().rstrip("=")
            if not hmac.compare_digest(good, sig) or int(expiry) < time.time():
                return None
        except ValueError:
            return None
        return self.by_id(key_id)


def load_keys(path: Path, defaults: Limits) -> KeyRing:
    """The keys of ``path`` (YAML or JSON); :class:`KeysError` names what is wrong."""
    import yaml

    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise KeysError(f"API keys file {path}: cannot be read ({exc.strerror})") from None
    try:
        data = yaml.safe_load(raw) if path.suffix.lower() != ".json" else json.loads(raw)
        doc = KeysFile.model_validate(data)
    except (yaml.YAMLError, ValueError) as exc:
        if isinstance(exc, ValidationError):
            e = exc.errors()[0]
            where = ".".join(str(p) for p in e["loc"])
            raise KeysError(f"API keys file {path}: {where}: {e['msg']}") from None
        raise KeysError(f"API keys file {path}: not valid YAML or JSON") from None
    entries: dict[str, KeyEntry] = {}
    ids = set()
    for e in doc.keys:
        bad = [s for s in e.scopes if s not in SCOPES]
        if bad:
            raise KeysError(f"API keys file {path}: key {e.id}: unknown scope {bad[0]!r} "
                            f"(scopes: {', '.join(SCOPES)})")
        if e.id in ids or e.sha256 in entries:
            raise KeysError(f"API keys file {path}: key {e.id} is listed twice")
        ids.add(e.id)
        entries[e.sha256] = e
    secret = hashlib.sha256(b"excite-live-ticket\0" + raw).digest()
    return KeyRing(entries, secret, defaults)


# --------------------------------------------------------------------------------------------
# Request rates


@dataclass
class _Bucket:
    tokens: float
    at: float


@dataclass
class RateLimiter:
    """A token bucket per key (in this replica: N replicas behind a balancer allow up to N
    times the rate); at most ``max_keys`` buckets are kept (least recently used dropped)."""

    max_keys: int = 10_000
    _buckets: OrderedDict = field(default_factory=OrderedDict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def take(self, key: str, rate: float, burst: int) -> float:
        """0 when the request may go, else the seconds until it may."""
        now = time.monotonic()
        with self._lock:
            b = self._buckets.pop(key, None) or _Bucket(float(burst), now)
            b.tokens = min(float(burst), b.tokens + (now - b.at) * rate)
            b.at = now
            self._buckets[key] = b
            while len(self._buckets) > self.max_keys:
                self._buckets.popitem(last=False)
            if b.tokens >= 1.0:
                b.tokens -= 1.0
                return 0.0
            return (1.0 - b.tokens) / rate


# --------------------------------------------------------------------------------------------
# The dependencies


def _unauthorized(detail: str) -> ProblemError:
    return ProblemError(401, detail, type_="unauthorized", title="Unauthorized",
                        errors=[{"field": "X-API-Key", "message": detail}],
                        headers={"WWW-Authenticate": 'APIKey, Bearer realm="excite"'})


async def authorize(security_scopes: SecurityScopes, conn: HTTPConnection,
              key: Annotated[str | None, Depends(key_header)],
              credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
              ticket: Annotated[str | None, Depends(ticket_query)]) -> Principal:
    """The request's principal, with every scope of ``security_scopes``, within its rate (a few
    microseconds: run in the event loop, no thread hop)."""
    ctx = getattr(conn.app.state, "ctx", None)
    ring: KeyRing | None = None if ctx is None else ctx.keys
    if ring is None:  # an open server (or the routers alone, without the service's context)
        return OPEN
    principal = None
    secret = key or (credentials.credentials if credentials is not None else None)
    if secret:
        principal = ring.lookup(secret)
        if principal is None:
            raise _unauthorized("the API key is not one of this server's")
    elif ticket and conn.scope["type"] == "websocket":
        principal = ring.redeem(ticket)
        if principal is None:
            raise _unauthorized("the live ticket is not valid or has expired (tickets last "
                                f"{TICKET_TTL_S:g} s)")
    if principal is None:
        raise _unauthorized("this server needs an API key: send it as X-API-Key or "
                            "Authorization: Bearer")
    missing = [s for s in security_scopes.scopes if not principal.allows(s)]
    if missing:
        raise ProblemError(403, f"the key {principal.key_id} lacks the scope {missing[0]!r} "
                                f"(it has: {', '.join(sorted(principal.scopes))})",
                           type_="forbidden", title="Forbidden",
                           errors=[{"field": "X-API-Key", "message": f"needs scope {missing[0]}"}])
    limits = principal.limits
    if limits is not None and conn.scope["type"] == "http":
        wait = ctx.rates.take(principal.key_id, limits.rate_per_s, limits.burst)
        if wait > 0:
            retry = max(1, int(wait + 0.999))
            raise ProblemError(429, f"the key {principal.key_id} is over its rate of "
                                    f"{limits.rate_per_s:g} requests per second (burst {limits.burst}); "
                                    f"retry in {retry} s", type_="rate-limited",
                               headers={"Retry-After": str(retry)})
    return principal


async def problem_or_principal(security_scopes: SecurityScopes, conn: HTTPConnection,
                         key: Annotated[str | None, Depends(key_header)],
                         credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(bearer)],
                         ticket: Annotated[str | None, Depends(ticket_query)]) -> Principal | ProblemError:
    """:func:`authorize` for a WebSocket, whose refusal is a problem frame after the accept."""
    try:
        return await authorize(security_scopes, conn, key, credentials, ticket)
    except ProblemError as exc:
        return exc


Anyone = Annotated[Principal, Security(authorize)]  # any valid key
Scorer = Annotated[Principal, Security(authorize, scopes=["score"])]
Planner = Annotated[Principal, Security(authorize, scopes=["plan"])]
Admin = Annotated[Principal, Security(authorize, scopes=["admin"])]
LiveClient = Annotated[Principal | ProblemError, Security(problem_or_principal, scopes=["score"])]


# --------------------------------------------------------------------------------------------
# Exposure


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or a name) is only reachable from this machine."""
    if host in ("localhost", "ip6-localhost"):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        pass
    try:
        addrs = {info[4][0] for info in socket.getaddrinfo(host, None)}
    except OSError:
        return False
    return bool(addrs) and all(ipaddress.ip_address(a.split("%")[0]).is_loopback for a in addrs)


def check_exposure(host: str, has_keys: bool, open_access: bool) -> None:
    """Refuse to serve without keys on an address others can reach, unless told it is open."""
    if has_keys or open_access or is_loopback(host):
        return
    raise Exposed(f"refusing to serve {host} without API keys: anyone who reaches it could use it; "
                  "set EXCITE_API_KEYS_FILE (python -m api.keys new), or EXCITE_OPEN=true to serve it "
                  "open on purpose")


