"""``/v1/live``: a WebSocket on which a vehicle streams its poses during the calibration drive and
receives the live guidance of :mod:`excite.score.live` (the same updates as ``excite live --json``,
or a drivable ``plan``'s as :class:`excite.plan.drivable.guide.PlanStream` gives them). The protocol,
its bounds and close codes are in ``docs/guides/live.md``; the bounds are this module's constants
and the settings'. Each session's evaluator runs in a process of its own (:class:`Session`): the
event loop holds only the socket. A browser authenticates with a single-use ticket offered as the
subprotocol ``excite-ticket.<ticket>`` beside ``excite-live``.
"""

from __future__ import annotations

import json
import logging
import math
import re
import time
from typing import Any

import anyio
from fastapi import APIRouter, Request, WebSocket, WebSocketDisconnect

from excite.core.bounds import nesting, tightened
from excite.core.processes import Supervised
from excite.errors import WorkerDied, WorkTimeout

from .. import auth
from ..auth import LIVE_PROTOCOL, LiveClient, RateLimiter, Scorer
from ..context import Ctx, Context
from ..errors import Problem, Refusal
from ..pool import forkserver, trim
from ..schemas import SCENE_PATTERN
from ..scoring import resolve_rig, scene_of, scene_spec, task

log = logging.getLogger("excite.api")
router = APIRouter(prefix="/v1", tags=["live"])

MAX_MESSAGE_BYTES = 1 << 20
MAX_POSES = 5000
MAX_DEPTH = 8  # a poses message is 3 levels deep
MAX_MESSAGES_PER_S = 50.0
BURST = 100
IDLE_S = 60.0  # a session that sends nothing for this long is closed (its slot freed)
MAX_SESSIONS = 64  # the ceiling of EXCITE_MAX_LIVE_SESSIONS (16 by default), whatever it says
_messages = RateLimiter()  # per session


def refused(status: int, field: str, message: str, close_code: int | None = None) -> Refusal:
    return Refusal(Problem.at(field, message, status), close_code)


def _number(text: str) -> float | int:
    # an integer too large for a float (1 followed by 400 digits) is refused as non-finite later
    return int(text) if len(text) <= 18 else float(text)


def _message(text: str) -> dict[str, Any]:
    if len(text.encode("utf-8")) > MAX_MESSAGE_BYTES:
        raise refused(413, "message", f"over the limit of {MAX_MESSAGE_BYTES} bytes")
    deep = refused(422, "message", f"nested more than {MAX_DEPTH} levels deep")
    try:
        msg = json.loads(text, parse_int=_number)
    except RecursionError:
        raise deep from None
    except ValueError as exc:
        detail = f"{exc.msg} at character {exc.pos}" if isinstance(exc, json.JSONDecodeError) else str(exc)[:200]
        raise refused(400, "message", f"not JSON ({detail})") from None
    if nesting(msg, MAX_DEPTH) > MAX_DEPTH:
        raise deep
    if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
        raise refused(422, "type", "each message is an object with a string field 'type'")
    return msg


def _finite_number(x: Any) -> bool:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return False
    try:
        return math.isfinite(x)
    except OverflowError:
        return False


def _rows(msg: dict[str, Any], field: str, width: int, required: bool) -> list[list[float]] | None:
    rows = msg.get(field)
    if rows is None and not required:
        return None
    if not isinstance(rows, list) or not rows:
        raise refused(422, field, f"must be a non-empty array of [{width} numbers] rows")
    if len(rows) > MAX_POSES:
        raise refused(413, field, f"{len(rows)} rows, over the limit of {MAX_POSES} per message")
    for i, r in enumerate(rows):
        if not (isinstance(r, list) and len(r) == width and all(_finite_number(x) for x in r)):
            raise refused(422, f"{field}[{i}]", f"must be {width} finite numbers")
        if any(abs(x) > 1e12 for x in r):
            raise refused(422, f"{field}[{i}]", "a number beyond ±1e12")
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
        raise refused(422, f"poses[{k}]", f"the quaternion has norm {norm[k]:.6g}, not 1")
    return d[:, 0], d[:, 1:4], Rotation.from_quat(d[:, 4:8] / norm[:, None]).as_matrix()


class Drive:
    """What the server keeps of a session to bound it: the pose count, first and last time."""

    def __init__(self, s: Any):
        self.max_poses, self.max_s, self.max_rate = s.max_samples, s.max_route_duration_s, s.max_live_pose_rate_hz
        self.n, self.t0, self.t_last = 0, None, None

    def check(self, t: Any) -> None:
        n = len(t)
        if self.n + n > self.max_poses:
            raise refused(413, "poses", f"the drive would hold {self.n + n} poses, over the limit of "
                                        f"{self.max_poses} (EXCITE_MAX_SAMPLES)")
        t0 = float(t[0]) if self.t0 is None else self.t0
        span = float(t[-1]) - t0
        if span > self.max_s:
            raise refused(422, "poses", f"the drive would last {span:.1f} s, over the limit of "
                                        f"{self.max_s:g} s (EXCITE_MAX_ROUTE_DURATION_S)")
        start = float(t[0]) if self.t_last is None else self.t_last
        if n >= 2 or self.t_last is not None:
            steps = n - 1 if self.t_last is None else n
            dt = float(t[-1]) - start
            if steps > 0 and steps > self.max_rate * max(dt, 0.0) + 1:
                rate = steps / dt if dt > 0 else math.inf
                raise refused(422, "poses", f"{steps} poses in {dt:.3g} s ({rate:.4g} Hz), denser than "
                                            f"the limit of {self.max_rate:g} Hz (EXCITE_MAX_LIVE_POSE_RATE_HZ)")
        self.n += n
        self.t0, self.t_last = t0, float(t[-1])


# --------------------------------------------------------------------------------------------
# The session's process


def _session_main(conn: Any, rig: Any, name: str, duration_s: float, length_m: float, plan: Any = None,
                  scene: tuple | None = None) -> None:
    """A session's evaluator: the rig and the scene resolved here (a client's rig can cost seconds
    to check, a scene to read), then each ``("poses", t, p, R)`` or ``("end",)`` answered
    ``("ok", value)`` or ``("problem", Problem)``; every failure is a problem
    (:func:`api.scoring.task`)."""
    with tightened(duration_s=duration_s, length_m=length_m):
        try:
            r = task(resolve_rig, rig, field="rig")
            world = task(scene_of, scene, field="scene")
            stream = task(_stream, r, name, plan, world, field="plan")
        except Problem as exc:
            conn.send(("problem", exc))
            return
        conn.send(("ok", {"rig": r.name, "parameters": [c.name for c in r.scored],
                          "scene": None if world is None else {"name": world.source, "digest": world.digest}}))
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                return
            try:
                out: Any = ("ok", task(stream.add, *msg[1:], field="poses") if msg[0] == "poses" else
                            task(stream.finish, field="poses"))
            except Problem as exc:
                out = ("problem", exc)
            trim()
            conn.send(out)
            if out[0] != "ok" or msg[0] == "end":
                return


def _stream(rig: Any, name: str, plan: dict[str, Any] | None, scene: Any) -> Any:
    """The live evaluator of a session, following ``plan`` (a drivable plan's plan.json) if given."""
    from excite.score.live import PoseStream

    if plan is None:
        return PoseStream(rig, name=name, scene=scene)
    from excite.plan.drivable.guide import PlanStream
    from excite.plan.drivable.plan import plan_from_dict

    return PlanStream(rig, plan_from_dict(plan, "plan"), name=name, scene=scene)


class Session:
    """One session's evaluator in a supervised process (forked from the scoring pool's
    forkserver, with ``EXCITE_LIVE_MEMORY_MB``); every call has the request time limit."""

    def __init__(self, s: Any, rig: Any, name: str, plan: Any = None, scene: tuple | None = None):
        self.timeout_s = s.request_timeout_s
        self.proc = Supervised(_session_main, rig, name, s.max_route_duration_s, s.max_route_length_m, plan, scene,
                               context=forkserver(), memory_mb=s.live_memory_mb, name="excite-live")
        self.memory_mb = s.live_memory_mb

    def call(self, *msg: Any) -> Any:
        """Runs in a thread: the reply to ``msg`` (``()``: the start's), or :class:`Refusal`."""
        try:
            if msg:
                self.proc.send(msg)
            kind, value = self.proc.receive(time.monotonic() + self.timeout_s)
        except WorkTimeout:
            self.proc.stop()
            raise refused(503, "poses", f"the update took longer than the time limit of {self.timeout_s:g} s") from None
        except WorkerDied:
            if self.proc.proc.exitcode not in (None, 0, 70):  # killed: most likely by its memory limit
                raise refused(413, "poses", f"the drive needs more memory than a live session may use "
                                            f"({self.memory_mb} MiB, EXCITE_LIVE_MEMORY_MB)") from None
            raise refused(503, "session", "the session's process ended unexpectedly") from None
        if kind == "problem":
            raise Refusal(value)
        return value


# --------------------------------------------------------------------------------------------
# The socket


@router.post("/live/tickets", summary="A ticket for a browser's /v1/live WebSocket (60 s, one session)")
def ticket(request: Request, ctx: Ctx, who: Scorer) -> dict[str, Any]:
    """A browser cannot set headers on a WebSocket: it offers this ticket as the subprotocol
    ``excite-ticket.<ticket>`` (with ``excite-live``) instead of its key. A ticket opens one
    session within 60 s. On an open server no ticket is needed (``null``)."""
    if ctx.keys is None:
        return {"ticket": None, "expires_in_s": None}
    return {"ticket": auth.ticket(request.app.state.ticket_secret, who.key_id), "expires_in_s": auth.TICKET_TTL_S}


def _start(msg: dict[str, Any]) -> tuple[Any, str, Any, str | None]:
    if msg["type"] != "start":
        raise refused(422, "type", f"the first message must be 'start', got {msg['type']!r}")
    rig = msg.get("rig", "robotaxi")
    if not isinstance(rig, (str, dict)):
        raise refused(422, "rig", "must be a bundled rig name or a rig object")
    name = msg.get("name", "live")
    if not isinstance(name, str) or len(name) > 200:
        raise refused(422, "name", "must be a string of at most 200 characters")
    plan = msg.get("plan")
    if plan is not None and not isinstance(plan, dict):
        raise refused(422, "plan", "must be a drivable plan object (plan.json of excite optimize --drivable)")
    scene = msg.get("scene")
    if scene is not None and not (isinstance(scene, str) and re.match(SCENE_PATTERN, scene)):
        raise refused(422, "scene", "must be a bundled scene's name or the digest of an uploaded scene")
    return rig, name, plan, scene


@router.websocket("/live")
async def live(ws: WebSocket, ctx: Ctx, who: LiveClient) -> None:
    settings, counts = ctx.settings, ctx.live_sessions
    await ws.accept(subprotocol=LIVE_PROTOCOL if LIVE_PROTOCOL in ws.scope.get("subprotocols", ()) else None)
    if isinstance(who, Problem):
        await _refuse(ws, Refusal(who))
        return
    limit = min(settings.max_live_sessions, MAX_SESSIONS)
    if sum(counts.values()) >= limit:
        await _refuse(ws, refused(503, "session", f"{limit} sessions are streaming already; try again later", 1013))
        return
    mine = counts.get(who.key_id, 0)
    if who.limits is not None and mine >= who.limits.live_sessions:
        await _refuse(ws, refused(429, "session", f"the key {who.key_id} has {mine} sessions streaming "
                                                  f"(its quota: {who.limits.live_sessions})", 1013))
        return
    counts[who.key_id] = mine + 1
    try:
        await _session(ws, settings, ctx, who)
    except WebSocketDisconnect:
        pass  # the client went away: its stream is dropped with this frame
    except Exception:
        log.exception("live session failed")
        try:
            await _refuse(ws, refused(500, "session", "the server failed; the error is logged"))
        except Exception:
            pass
    finally:
        left = counts.get(who.key_id, 1) - 1
        if left:
            counts[who.key_id] = left
        else:
            counts.pop(who.key_id, None)


async def _receive_text(ws: WebSocket) -> str | None:
    """The next text frame; None after :data:`IDLE_S` of silence. A binary frame is refused."""
    with anyio.move_on_after(IDLE_S):
        message = await ws.receive()
        if message["type"] == "websocket.disconnect":
            raise WebSocketDisconnect(message.get("code", 1000))
        if message.get("text") is None:
            raise refused(422, "message", "binary frames are not accepted: send JSON text frames", 1003)
        return message["text"]
    return None


async def _session(ws: WebSocket, settings: Any, ctx: Context, who: Any) -> None:
    name_of_session = f"session-{id(ws)}"
    session: Session | None = None
    drive = Drive(settings)
    try:
        while True:
            try:
                text = await _receive_text(ws)
                if text is None:
                    raise refused(408, "session", f"no message for {IDLE_S:g} s")
                if _messages.take(name_of_session, MAX_MESSAGES_PER_S, BURST) > 0:
                    raise refused(429, "message", f"more than {MAX_MESSAGES_PER_S:g} messages per second")
                msg = await anyio.to_thread.run_sync(_message, text)  # 1 MB of JSON: not in the event loop
                if session is None:
                    rig, name, plan, scene_ref = _start(msg)
                    scene = await anyio.to_thread.run_sync(scene_spec, ctx.store, who.key_id, scene_ref)
                    # starting the process writes the rig to it (1 MB): not in the event loop either
                    session = await anyio.to_thread.run_sync(Session, settings, rig, name, plan, scene)
                    started = await anyio.to_thread.run_sync(session.call)
                    await ws.send_json({"type": "started", **started})
                    continue
                if msg["type"] == "poses":
                    t, p, R = _poses(_rows(msg, "poses", 8, True))
                    _rows(msg, "imu", 7, False)
                    drive.check(t)
                    for update in await anyio.to_thread.run_sync(session.call, "poses", t, p, R):
                        await ws.send_json(update)
                elif msg["type"] == "end":
                    final = await anyio.to_thread.run_sync(session.call, "end")
                    await ws.send_json(final)
                    await ws.close(1000)
                    return
                else:
                    raise refused(422, "type", f"expected 'poses' or 'end', got {msg['type']!r}")
            except (Refusal, Problem) as exc:  # a problem: the start's scene
                await _refuse(ws, exc if isinstance(exc, Refusal) else Refusal(exc))
                return
    finally:
        _messages.forget(name_of_session)
        if session is not None:
            await anyio.to_thread.run_sync(session.proc.stop)


async def _refuse(ws: WebSocket, exc: Refusal) -> None:
    await ws.send_json({"type": "error", "problem": exc.problem.body("/v1/live")})
    await ws.close(exc.close_code)
