"""``/v1/live``: a WebSocket on which a vehicle streams its poses during the calibration drive and
receives the live guidance of :mod:`excite.score.live` (the same updates as ``excite live --json``).

Protocol (text frames, one JSON object each):

- client → ``{"type": "start", "rig": "robotaxi" | {inline rig}, "name": "drive 7"}`` first;
- client → ``{"type": "poses", "poses": [[t, x, y, z, qx, qy, qz, qw], ...],
  "imu": [[t, wx, wy, wz, ax, ay, az], ...]}`` (``imu`` optional: checked, not used: the
  model's IMU factor is predicted from the pose trajectory, as in batch evaluation);
- client → ``{"type": "end"}``: the server answers the ``final`` update (``excite score`` on the
  same poses) and closes;
- server → ``update`` (about once per second of drive), ``done`` (``passed``: every parameter
  within target, once; or, ``passed`` false, nothing more gained from the motion so far, with
  the ``needs`` of each parameter short of target: again only after the motion changed), ``final``; on bad input ``{"type": "error", "problem": {RFC 9457 fields}}`` and the
  connection closes (1008; 1009 for a message over :data:`MAX_MESSAGE_BYTES`; 1013 when
  :data:`MAX_SESSIONS` are already streaming).

Bounds: a message is at most :data:`MAX_MESSAGE_BYTES` (uvicorn's ``ws_max_size`` bounds the
frame before it is read) and :data:`MAX_POSES` poses; a session sends at most
:data:`MAX_MESSAGES_PER_S` messages per second on average (burst :data:`BURST`) and is closed after
:data:`IDLE_S` without a message. A session's state lives in its handler only: a broken
connection frees everything.
"""

from __future__ import annotations

import json
import math
import time
from typing import Any

import anyio
from fastapi import APIRouter, WebSocket, WebSocketDisconnect

from excite.errors import ExciteError
from excite.score.live import PoseStream

from ..problems import TYPE_BASE
from ..scoring import resolve_rig
from ..errors import Refused, Rejected

router = APIRouter(prefix="/v1", tags=["live"])

MAX_MESSAGE_BYTES = 1 << 20
MAX_POSES = 5000
MAX_MESSAGES_PER_S = 50.0
BURST = 100
MAX_SESSIONS = 16
IDLE_S = 60.0  # a session that sends nothing for this long is closed (its slot freed)
_sessions = {"open": 0}  # sessions streaming right now (all in this event loop)


def problem(status: int, field: str, message: str) -> dict[str, Any]:
    """The error frame: the fields of an RFC 9457 problem document."""
    kind = {408: "timeout", 413: "too-large", 422: "validation", 429: "rate-limited",
            503: "unavailable"}.get(status, "http-error")
    title = {408: "Request timeout", 413: "Content too large", 422: "Unprocessable content",
             429: "Too many requests", 503: "Service unavailable"}.get(status, "Bad request")
    return {"type": "error", "problem": {"type": TYPE_BASE + kind, "title": title, "status": status,
                                         "detail": f"{field}: {message}",
                                         "errors": [{"field": field, "message": message}]}}


class _Bucket:
    """Token bucket: ``rate`` messages per second on average, ``burst`` at once."""

    def __init__(self, rate: float, burst: int):
        self.rate, self.burst, self.tokens, self.at = rate, burst, float(burst), time.monotonic()

    def take(self) -> bool:
        now = time.monotonic()
        self.tokens = min(self.burst, self.tokens + (now - self.at) * self.rate)
        self.at = now
        if self.tokens < 1:
            return False
        self.tokens -= 1
        return True


def _message(text: str) -> dict[str, Any]:
    if len(text.encode("utf-8")) > MAX_MESSAGE_BYTES:
        raise Refused(413, "message", f"over the limit of {MAX_MESSAGE_BYTES} bytes", 1009)
    try:
        msg = json.loads(text)
    except ValueError as exc:
        raise Refused(400, "message", f"not JSON ({exc.msg} at character {exc.pos})") from None
    if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
        raise Refused(422, "type", "each message is an object with a string field 'type'")
    return msg


def _rows(msg: dict[str, Any], field: str, width: int, required: bool) -> list[list[float]] | None:
    rows = msg.get(field)
    if rows is None and not required:
        return None
    if not isinstance(rows, list) or not rows:
        raise Refused(422, field, f"must be a non-empty array of [{width} numbers] rows")
    if len(rows) > MAX_POSES:
        raise Refused(413, field, f"{len(rows)} rows, over the limit of {MAX_POSES} per message")
    for i, r in enumerate(rows):
        if not (isinstance(r, list) and len(r) == width
                and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in r)):
            raise Refused(422, f"{field}[{i}]", f"must be {width} finite numbers")
    return rows


def _poses(rows: list[list[float]]):
    import numpy as np
    from scipy.spatial.transform import Rotation

    from excite.io.routes import QUAT_NORM_TOL

    d = np.asarray(rows, dtype=float)
    norm = np.linalg.norm(d[:, 4:8], axis=1)
    bad = np.abs(norm - 1.0) > QUAT_NORM_TOL
    if bad.any():
        k = int(np.argmax(bad))
        raise Refused(422, f"poses[{k}]", f"the quaternion has norm {norm[k]:.6g}, not 1")
    return d[:, 0], d[:, 1:4], Rotation.from_quat(d[:, 4:8] / norm[:, None]).as_matrix()


def _start(msg: dict[str, Any]) -> PoseStream:
    if msg["type"] != "start":
        raise Refused(422, "type", f"the first message must be 'start', got {msg['type']!r}")
    rig = msg.get("rig", "robotaxi")
    if not isinstance(rig, (str, dict)):
        raise Refused(422, "rig", "must be a bundled rig name or a rig object")
    name = msg.get("name", "live")
    if not isinstance(name, str) or len(name) > 200:
        raise Refused(422, "name", "must be a string of at most 200 characters")
    try:
        r = resolve_rig(rig)
    except Rejected as exc:
        raise Refused(exc.status, exc.field, exc.message) from None
    return PoseStream(r, name=name)


@router.websocket("/live")
async def live(ws: WebSocket) -> None:
    await ws.accept()
    if _sessions["open"] >= MAX_SESSIONS:
        await _refuse(ws, Refused(503, "session", f"{MAX_SESSIONS} sessions are streaming already; "
                                                   "try again later", 1013))
        return
    _sessions["open"] += 1
    try:
        await _session(ws)
    except WebSocketDisconnect:
        pass  # the client went away: its stream is dropped with this frame
    finally:
        _sessions["open"] -= 1


async def _session(ws: WebSocket) -> None:
    bucket = _Bucket(MAX_MESSAGES_PER_S, BURST)
    stream: PoseStream | None = None
    while True:
        with anyio.move_on_after(IDLE_S) as idle:
            text = await ws.receive_text()
        if idle.cancelled_caught:
            await _refuse(ws, Refused(408, "session", f"no message for {IDLE_S:g} s"))
            return
        try:
            if not bucket.take():
                raise Refused(429, "message", f"more than {MAX_MESSAGES_PER_S:g} messages per second", 1008)
            msg = _message(text)
            if stream is None:
                stream = _start(msg)
                await ws.send_json({"type": "started", "rig": stream.rig.name,
                                    "parameters": [c.name for c in stream.rig.scored]})
                continue
            if msg["type"] == "poses":
                t, p, R = _poses(_rows(msg, "poses", 8, True))
                _rows(msg, "imu", 7, False)
                for update in await anyio.to_thread.run_sync(stream.add, t, p, R):
                    await ws.send_json(update)
            elif msg["type"] == "end":
                final = await anyio.to_thread.run_sync(stream.finish)
                await ws.send_json(final)
                await ws.close(1000)
                return
            else:
                raise Refused(422, "type", f"expected 'poses' or 'end', got {msg['type']!r}")
        except Refused as exc:
            await _refuse(ws, exc)
            return
        except ExciteError as exc:
            await _refuse(ws, Refused(422, "poses", str(exc)))
            return


async def _refuse(ws: WebSocket, exc: Refused) -> None:
    await ws.send_json(problem(exc.status, exc.field, exc.message))
    await ws.close(exc.close_code)
