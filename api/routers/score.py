"""``POST /v1/score``: one route and a rig → the evaluator's report."""

from __future__ import annotations

import json
import math
import tempfile
from pathlib import Path
from typing import Any

import anyio
from fastapi import APIRouter, Request
from fastapi.responses import JSONResponse, Response
from fastapi.routing import APIRoute
from starlette.routing import Match

from ..auth import Scorer
from ..context import Ctx, raise_problem
from ..errors import ProblemError
from ..scoring import bag_score_task
from ..schemas import PlotRequest, ScoreRequest, ScoreResponse
from .common import SCORED

router = APIRouter(prefix="/v1", tags=["score"])


@router.post("/score", response_model=ScoreResponse, responses=SCORED,
             summary="Score a route: how well does it determine every calibration parameter?")
def score(body: ScoreRequest, ctx: Ctx, who: Scorer) -> Any:
    """The route is given inline (file text with its format, JSON waypoints, timed poses or a
    control profile); the rig by bundled name or inline. CPU-bound: runs in a worker process.

    A bag is scored by posting it to the same path as ``multipart/form-data``: fields ``bag``
    (the ``.bag`` or ``.mcap`` file), ``topic`` (pose topic or TF chain ``/tf:PARENT.CHILD``),
    optional ``imu_topic``, ``rig`` (bundled name or inline JSON), ``start_s``, ``end_s``,
    ``segments``, ``vehicle_frame``, ``axes``. The upload is spooled to disk within the body
    limit; a truncated or corrupt bag is a 422 naming the problem."""
    limits = body.limits.model_dump() if body.limits else None
    futures = ctx.submit_scores([(body.route.model_dump(), "route")], body.rig, body.segments, limits,
                                ctx.deadline(), track_points=body.track_points)
    (result,) = ctx.wait(futures)
    if not result["ok"]:
        raise_problem(result)
    return {**result["report"], "track": result.get("track")}


@router.post("/score/plot", response_class=Response, summary="The report of a route as a figure (PNG)",
             responses={**SCORED, 200: {"content": {"image/png": {}},
                                      "description": "route coloured by information, scaled spectrum, σ/target"}})
def score_plot(body: PlotRequest, ctx: Ctx, who: Scorer) -> Response:
    """The same figure as ``excite score ROUTE --plot FILE.png``: the route coloured by the
    information it carries on ``parameter`` (or the weakest mode), the scaled spectrum with the
    pass line, and σ against target per parameter."""
    limits = body.limits.model_dump() if body.limits else None
    fut = ctx.submit_plot(body.route.model_dump(), body.rig, body.segments, limits, body.parameter,
                          ctx.deadline())
    (result,) = ctx.wait([fut])
    if not result["ok"]:
        raise_problem(result)
    return Response(content=result["png"], media_type="image/png")


# --------------------------------------------------------------------------------------------
# Bag uploads: the same path, multipart/form-data


class _MultipartRoute(APIRoute):
    """Matches only multipart requests, so that ``POST /v1/score`` takes a JSON route or a bag
    upload by its content type (this route is registered first)."""

    def matches(self, scope: dict) -> tuple[Match, dict]:
        headers = dict(scope.get("headers", []))
        if not headers.get(b"content-type", b"").lower().startswith(b"multipart/form-data"):
            return Match.NONE, {}
        return super().matches(scope)


bag_router = APIRouter(prefix="/v1", tags=["score"], route_class=_MultipartRoute)
_BAG_SUFFIXES = (".bag", ".mcap")
_FIELDS = ("bag", "topic", "imu_topic", "rig", "start_s", "end_s", "segments", "vehicle_frame", "axes")


def _number(form: Any, key: str, kind: type) -> Any:
    value = form.get(key)
    if value is None or value == "":
        return None
    try:
        x = kind(value)
        finite = math.isfinite(x)
    except (TypeError, ValueError, OverflowError):
        raise ProblemError(422, f"{key}: expected a number, got {value[:40]!r}",
                           errors=[{"field": key, "message": "expected a number"}]) from None
    if not finite:
        raise ProblemError(422, f"{key}: must be finite", errors=[{"field": key, "message": "must be finite"}])
    return x


def _invalid(key: str, message: str) -> ProblemError:
    return ProblemError(422, f"{key}: {message}", errors=[{"field": key, "message": message}])


MAX_FIELD_BYTES = 1 << 20  # a form field other than the bag (an inline rig as JSON is a few KiB)


class _Form:
    """A multipart body parsed as it arrives: the ``bag`` part written straight to ``path`` (the
    one copy on disk), the other fields kept as text (each at most :data:`MAX_FIELD_BYTES`)."""

    def __init__(self, boundary: bytes, path: Path):
        from python_multipart.multipart import MultipartParser

        self.path, self.fields, self.filename = path, {}, None
        self.file = None
        self.bag_bytes = 0
        self._name: str | None = None
        self._buf = bytearray()
        self._headers: dict[bytes, bytes] = {}
        self._hname = bytearray()
        self._hvalue = bytearray()
        self.error: ProblemError | None = None
        self.parser = MultipartParser(boundary, {
            "on_part_begin": self._begin, "on_part_data": self._data, "on_part_end": self._end,
            "on_header_field": lambda d, a, b: self._hname.extend(d[a:b]),
            "on_header_value": lambda d, a, b: self._hvalue.extend(d[a:b]),
            "on_header_end": self._header_end, "on_headers_finished": self._headers_done})

    def _begin(self) -> None:
        self._name, self._headers = None, {}
        self._buf = bytearray()

    def _header_end(self) -> None:
        self._headers[bytes(self._hname).lower()] = bytes(self._hvalue)
        self._hname, self._hvalue = bytearray(), bytearray()

    def _headers_done(self) -> None:
        from python_multipart.multipart import parse_options_header

        _, opts = parse_options_header(self._headers.get(b"content-disposition", b""))
        self._name = opts.get(b"name", b"").decode("utf-8", "replace")
        if self._name not in _FIELDS:
            self.fail(_invalid(self._name[:100], f"unknown field (fields: {', '.join(_FIELDS)})"))
        elif self._name == "bag":
            if self.file is not None:
                self.fail(_invalid("bag", "one bag per request"))
                return
            self.filename = opts.get(b"filename", b"").decode("utf-8", "replace")
            self.file = self.path.open("wb")
        elif self._name in self.fields:
            self.fail(_invalid(self._name, "given twice"))

    def _data(self, data: bytes, start: int, end: int) -> None:
        if self.error is not None:
            return
        if self._name == "bag" and self.file is not None:
            self.file.write(data[start:end])
            self.bag_bytes += end - start
        else:
            self._buf += data[start:end]
            if len(self._buf) > MAX_FIELD_BYTES:
                self.fail(_invalid(self._name or "form", f"over the limit of {MAX_FIELD_BYTES} bytes"))

    def _end(self) -> None:
        if self.error is None and self._name and self._name != "bag":
            try:
                self.fields[self._name] = self._buf.decode("utf-8")
            except UnicodeDecodeError:
                self.fail(_invalid(self._name, "not UTF-8 text"))

    def fail(self, error: ProblemError) -> None:
        if self.error is None:
            self.error = error

    def get(self, key: str) -> Any:
        return self.fields.get(key)

    def close(self) -> None:
        if self.file is not None and not self.file.closed:
            self.file.close()


@bag_router.post("/score", include_in_schema=False)
async def score_bag(request: Request, ctx: Ctx, who: Scorer) -> Any:
    """A bag upload (multipart/form-data): ``bag`` (a ``.bag`` or ``.mcap`` file), ``topic``
    (pose topic or ``/tf:PARENT.CHILD``), optional ``imu_topic``, ``rig`` (bundled name or inline
    JSON), ``start_s``/``end_s``, ``segments``, ``vehicle_frame``, ``axes``. The file is written
    to disk once, as it arrives (within the body limit), and deleted after scoring; a server
    whose temporary folder's disk is nearly full answers 503 before it writes."""
    from python_multipart.multipart import parse_options_header

    from .health import free_mb

    _, opts = parse_options_header(request.headers.get("content-type", ""))
    boundary = opts.get(b"boundary")
    if not boundary:
        raise ProblemError(400, "the multipart body has no boundary in its Content-Type")
    tmp_root = Path(tempfile.gettempdir())
    if free_mb(tmp_root) < ctx.settings.min_free_mb:
        raise ProblemError(503, "the server's temporary folder is nearly full; retry later",
                           type_="disk-full", headers={"Retry-After": "30"})
    with tempfile.TemporaryDirectory(prefix="excite-bag-") as tmp:
        form = _Form(boundary, Path(tmp) / "upload")
        try:
            async for chunk in request.stream():
                form.parser.write(chunk)
                if form.error is not None:
                    raise form.error
            form.parser.finalize()
        except ProblemError:
            raise
        except Exception as exc:  # python-multipart's parse errors
            if isinstance(exc, OSError):
                raise
            raise ProblemError(400, f"the multipart body cannot be parsed ({str(exc)[:200]})") from None
        finally:
            form.close()
        return await _score_form(form, ctx)


async def _score_form(form: _Form, ctx: Any) -> Any:
    """Validate the fields, name the spooled bag as its suffix says, score it in a worker."""
    if form.file is None:
        raise _invalid("bag", "required: the bag file (a ROS 1 .bag or an .mcap)")
    filename = Path(form.filename or "").name
    suffix = Path(filename).suffix.lower()
    if suffix not in _BAG_SUFFIXES:
        raise _invalid("bag", f"the file name must end in .bag or .mcap, got {filename[:200]!r}")
    topic = form.get("topic")
    if not isinstance(topic, str) or not topic:
        raise _invalid("topic", "required: a pose topic or a TF chain /tf:PARENT.CHILD")
    if len(topic) > 1000:
        raise _invalid("topic", "longer than 1000 characters")
    rig_text = form.get("rig") or "robotaxi"
    rig: Any = rig_text
    if rig_text.lstrip().startswith("{"):
        try:
            rig = json.loads(rig_text)
        except (json.JSONDecodeError, RecursionError) as exc:
            why = exc.msg if isinstance(exc, json.JSONDecodeError) else "nested too deeply"
            raise _invalid("rig", f"not valid JSON ({why})") from None
        if not isinstance(rig, dict):
            raise _invalid("rig", "expected a rig object")
    segments = _number(form, "segments", int) or 0
    if not 0 <= segments <= 1000:
        raise _invalid("segments", "must be between 0 and 1000")
    source = {"topic": topic, "imu_topic": form.get("imu_topic") or None,
              "start_s": _number(form, "start_s", float), "end_s": _number(form, "end_s", float),
              "vehicle_frame": form.get("vehicle_frame") or None, "axes": form.get("axes") or "vehicle"}
    path = form.path.with_name(f"upload{suffix}")
    form.path.rename(path)
    futures = ctx.submit(bag_score_task, [(str(path), filename, source, rig, segments, ctx.bounds)],
                         ctx.deadline())
    (result,) = await anyio.to_thread.run_sync(ctx.wait, futures)
    if not result["ok"]:
        raise_problem(result)
    return JSONResponse(result["report"])
