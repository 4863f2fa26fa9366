"""``GET /v1/rigs``: the bundled rigs and the parameters each estimates. ``POST /v1/rigs/parse``:
a rig YAML file → the rig config object the other requests take inline."""

from __future__ import annotations

import json
from typing import Any

import yaml
from fastapi import APIRouter

from excite.factors import base as registry
from excite.rig.config import Rig, bundled_rigs

from ..auth import Anyone
from ..errors import ProblemError, Rejected
from ..schemas import RigParsed, RigsResponse, RigYaml
from ..scoring import resolve_rig
from .common import AUTH, BODY

router = APIRouter(prefix="/v1", tags=["rigs"])


def _summary(name: str, rig: Rig) -> dict[str, Any]:
    return {"name": name, "description": rig.config.description,
            "keyframe_rate_hz": rig.keyframe_rate_hz,
            "sensors": [{"name": s.name, "kind": s.kind, "rate_hz": s.rate_hz}
                        for s in rig.config.sensors],
            # everything the rig measures, the sections too (imu, wheels, ackermann, …)
            "measurements": [{"name": i.name, "kind": i.kind.name} for i in registry.instances(rig)],
            "parameters": [{"name": c.name, "unit": c.unit, "target": c.target}
                           for c in rig.scored]}


@router.get("/rigs", response_model=RigsResponse, responses=AUTH, summary="Bundled rigs")
def rigs(who: Anyone) -> Any:
    return {"rigs": [_summary(name, resolve_rig(name)) for name in bundled_rigs()]}


def _yaml_problem(message: str) -> ProblemError:
    return ProblemError(422, f"yaml: {message}", errors=[{"field": "yaml", "message": message}])


@router.post("/rigs/parse", response_model=RigParsed, responses=BODY,
             summary="Read a rig YAML file: the config object to send as `rig`, and its parameters")
def parse_rig(body: RigYaml, who: Anyone) -> Any:
    """For clients that cannot read YAML (the page): the file's mapping, checked as a rig.
    Anchors and aliases are refused (a few nested aliases expand to gigabytes)."""
    try:
        if any(isinstance(ev, yaml.AliasEvent) for ev in yaml.parse(body.yaml, Loader=yaml.SafeLoader)):
            raise _yaml_problem("anchors and aliases (*name) are not accepted; write the values out")
        data = yaml.safe_load(body.yaml)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}: " if mark is not None else ""
        raise _yaml_problem(f"{where}{getattr(exc, 'problem', None) or exc}") from None
    if not isinstance(data, dict):
        raise _yaml_problem("a rig file is a mapping (name:, imu:, sensors:, …)")
    try:
        json.dumps(data, allow_nan=False)
    except (TypeError, ValueError):
        raise _yaml_problem("holds values JSON cannot carry (dates, binary, NaN or infinity)") from None
    try:
        rig = resolve_rig(data)
    except Rejected as exc:
        raise ProblemError(exc.status, f"{exc.field}: {exc.message}",
                           errors=[{"field": exc.field, "message": exc.message}]) from None
    return {"rig": data, "summary": _summary(rig.name, rig)}
