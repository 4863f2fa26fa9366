"""Who may do what: API keys with scopes and an owner, checked from the request's headers before
its body is read, and each key's quotas. The keys file and what a client sends: the service guide
(docs/guides/service.md, "Keys, scopes and quotas").

:class:`Authenticate` resolves the key from the headers before a byte of the body is read (401,
429 over its rate); the routes' dependencies check scopes (``admin``: everything, every key's
jobs); a browser's WebSocket offers a single-use :func:`ticket` instead. Without a keys file the
server is open: everyone is :data:`OPEN` (admin, no quota), on loopback only unless
``EXCITE_OPEN=true`` (:func:`check_exposure`).
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
from typing import Annotated, Any, Callable

import anyio
from fastapi import Depends, Security
from fastapi.security import APIKeyHeader, HTTPBearer, SecurityScopes
from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model
from starlette.datastructures import Headers
from starlette.requests import HTTPConnection

from . import problems
from .errors import Exposed, KeysError, Problem
from .middleware import UNSAFE
from .settings import Settings
from .store import OPEN_KEY

SCOPES = ("score", "plan", "admin")
KEY_PREFIX = "exk_"
TICKET_TTL_S = 60.0
TICKET_PROTOCOL = "excite-ticket."  # a WebSocket subprotocol carrying a ticket
LIVE_PROTOCOL = "excite-live"  # the subprotocol the server answers with
NO_KEY = "this server needs an API key: send it as X-API-Key or Authorization: Bearer"

# declared so that the OpenAPI document states the credentials; the keys are read by Authenticate
key_header = APIKeyHeader(name="X-API-Key", auto_error=False, scheme_name="APIKey",
                          description="An API key the operator issued.")
bearer = HTTPBearer(auto_error=False, scheme_name="Bearer", description="The same API key as a bearer token.")


# A key's limits, each the server's EXCITE_QUOTA_* setting (its ``defaults``) where the keys file
# leaves it out; the same names, bounds and descriptions as those settings, stated there
Quota = create_model("Quota", __config__=ConfigDict(extra="forbid", frozen=True), **{
    name.removeprefix("quota_"): (Annotated[f.annotation, *f.metadata] | None, Field(None, description=f.description))
    for name, f in Settings.model_fields.items() if name.startswith("quota_")})


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
class Principal:
    """Who a request is: the key's id (jobs belong to it), its owner, scopes and limits
    (``limits`` None: no quota, an open server)."""

    key_id: str
    owner: str
    scopes: frozenset[str]
    limits: Quota | None = None

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
    """The keys of one file, by hash, with the server's default limits."""

    entries: dict[str, KeyEntry]
    defaults: Quota

    def lookup(self, key: str) -> Principal | None:
        entry = self.entries.get(hash_key(key))
        return None if entry is None else self.principal(entry)

    def by_id(self, key_id: str) -> Principal | None:
        entry = next((e for e in self.entries.values() if e.id == key_id), None)
        return None if entry is None else self.principal(entry)

    def principal(self, entry: KeyEntry) -> Principal:
        limits = self.defaults.model_copy(update=entry.quota.model_dump(exclude_none=True))
        return Principal(entry.id, entry.owner, frozenset(entry.scopes), limits)


def load_keys(path: Path, defaults: Quota) -> KeyRing:
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
    return KeyRing(entries, defaults)


# --------------------------------------------------------------------------------------------
# Tickets: key id, expiry and a nonce, signed with the store's shared secret


def ticket(secret: bytes, key_id: str, ttl_s: float = TICKET_TTL_S) -> str:
    body = f"{key_id}.{int(time.time() + ttl_s)}.{secrets.token_urlsafe(12)}"
    sig = hmac.new(secret, body.encode(), hashlib.sha256).digest()
    return body + "." + base64.urlsafe_b64encode(sig).decode().rstrip("=")


def ticket_claims(secret: bytes, text: str) -> tuple[str, float, str] | None:
    """(key id, expiry, nonce) of a ticket signed with ``secret`` that has not expired and
    expires within :data:`TICKET_TTL_S` (a signed ticket of longer life is refused too), or None."""
    try:
        key_id, expiry, nonce, sig = text.rsplit(".", 3)
        good = base64.urlsafe_b64encode(hmac.new(secret, f"{key_id}.{expiry}.{nonce}".encode(),
                                                 hashlib.sha256).digest()).decode().rstrip("=")
        if not hmac.compare_digest(good, sig):
            return None
        left = int(expiry) - time.time()
    except ValueError:
        return None
    if not 0 <= left <= TICKET_TTL_S + 1:
        return None
    return key_id, float(expiry), nonce


# --------------------------------------------------------------------------------------------
# Rates


@dataclass
class _Bucket:
    tokens: float
    at: float


@dataclass
class RateLimiter:
    """The service's one token bucket: ``take(name, rate, burst)`` per name (a key; a live
    session), at most ``max_names`` kept (least recently used dropped). Per replica: N replicas
    behind a balancer allow up to N times the rate."""

    max_names: int = 10_000
    _buckets: OrderedDict = field(default_factory=OrderedDict)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def take(self, name: str, rate: float, burst: int) -> float:
        """0 when one more may go now, else the seconds until it may."""
        now = time.monotonic()
        with self._lock:
            b = self._buckets.pop(name, None) or _Bucket(float(burst), now)
            b.tokens = min(float(burst), b.tokens + (now - b.at) * rate)
            b.at = now
            self._buckets[name] = b
            while len(self._buckets) > self.max_names:
                self._buckets.popitem(last=False)
            if b.tokens >= 1.0:
                b.tokens -= 1.0
                return 0.0
            return (1.0 - b.tokens) / rate

    def forget(self, name: str) -> None:
        with self._lock:
            self._buckets.pop(name, None)


# --------------------------------------------------------------------------------------------
# Authentication from the headers (ASGI), scopes in the routes' dependencies


def unauthorized(detail: str) -> Problem:
    return Problem(401, detail, errors=[{"field": "X-API-Key", "message": detail}],
                   headers={"WWW-Authenticate": 'APIKey, Bearer realm="excite"'})


def offered_ticket(scope: dict) -> str | None:
    """The ticket a WebSocket offers among its subprotocols (the ASGI scope's), if any."""
    return next((p[len(TICKET_PROTOCOL):] for p in scope.get("subprotocols", ()) if p.startswith(TICKET_PROTOCOL)),
                None)


class Authenticate:
    """Resolves the request's key from its headers before anything reads its body (see the module
    docstring) and leaves the :class:`Principal` (or None) in ``scope["state"]["principal"]``.
    ``ring`` None: an open server, everyone is :data:`OPEN`. ``redeem(ticket)`` → key id or None
    (a store call: run in a thread)."""

    def __init__(self, app: Any, ring: KeyRing | None, rates: RateLimiter,
                 redeem: Callable[[str], str | None]):
        self.app, self.ring, self.rates, self.redeem = app, ring, rates, redeem

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        try:
            who = await self._principal(scope)
        except Problem as exc:
            if scope["type"] == "websocket":
                scope.setdefault("state", {})["refusal"] = exc
                return await self.app(scope, receive, send)
            return await problems.send(send, exc, scope.get("path", ""), close=_has_body(scope))
        scope.setdefault("state", {})["principal"] = who
        await self.app(scope, receive, send)

    async def _principal(self, scope: dict) -> Principal | None:
        if self.ring is None:
            return OPEN
        headers = Headers(scope=scope)
        secret, auth = headers.get("x-api-key"), headers.get("authorization")
        if not secret and auth and auth[:7].lower() == "bearer ":
            secret = auth[7:].strip()
        if secret:
            who = self.ring.lookup(secret)
            if who is None:
                raise unauthorized("the API key is not one of this server's")
        elif scope["type"] == "websocket" and (ticket := offered_ticket(scope)):
            key_id = await anyio.to_thread.run_sync(self.redeem, ticket)
            who = None if key_id is None else self.ring.by_id(key_id)
            if who is None:
                raise unauthorized("the live ticket is not valid, was used already or has expired "
                                   f"(tickets last {TICKET_TTL_S:g} s and open one session)")
        elif _has_body(scope):
            raise unauthorized(NO_KEY)
        else:
            return None  # a read without a key: the route says whether it needs one
        if who.limits is not None and scope["type"] == "http":
            wait = self.rates.take(who.key_id, who.limits.rate_per_s, who.limits.burst)
            if wait > 0:
                retry = max(1, int(wait + 0.999))
                raise Problem(429, f"the key {who.key_id} is over its rate of {who.limits.rate_per_s:g} "
                                   f"requests per second (burst {who.limits.burst}); retry in {retry} s",
                              type_="rate-limited", headers={"Retry-After": str(retry)})
        return who


def _has_body(scope: dict) -> bool:
    if scope.get("method") in UNSAFE:
        return True
    headers = Headers(scope=scope)
    length = headers.get("content-length")
    return bool(length and length.strip() not in ("", "0")) or "transfer-encoding" in headers


async def authorize(security_scopes: SecurityScopes, conn: HTTPConnection,
                    _key: Annotated[str | None, Depends(key_header)],
                    _bearer: Annotated[Any, Depends(bearer)]) -> Principal:
    """The request's principal (resolved by :class:`Authenticate`), with every scope of
    ``security_scopes``. (The two header dependencies only declare the credentials in the
    OpenAPI document.)"""
    state = conn.scope.get("state", {})
    if "refusal" in state:
        raise state["refusal"]
    who = state.get("principal")  # None: no key sent (Authenticate)
    if who is None:
        raise unauthorized(NO_KEY)
    missing = [s for s in security_scopes.scopes if not who.allows(s)]
    if missing:
        raise Problem(403, f"the key {who.key_id} lacks the scope {missing[0]!r} "
                           f"(it has: {', '.join(sorted(who.scopes))})",
                      errors=[{"field": "X-API-Key", "message": f"needs scope {missing[0]}"}])
    return who


async def problem_or_principal(security_scopes: SecurityScopes, conn: HTTPConnection) -> Principal | Problem:
    """:func:`authorize` for a WebSocket (a ticket or a key), whose refusal is a problem frame
    after the accept. Declares no credential of its own: the OpenAPI document lists none."""
    try:
        return await authorize(security_scopes, conn, None, None)
    except Problem as exc:
        return exc


Anyone = Annotated[Principal, Security(authorize)]  # any valid key
Scorer = Annotated[Principal, Security(authorize, scopes=["score"])]
Planner = Annotated[Principal, Security(authorize, scopes=["plan"])]
LiveClient = Annotated[Principal | Problem, Security(problem_or_principal, scopes=["score"])]


# --------------------------------------------------------------------------------------------
# Exposure and hosts

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
