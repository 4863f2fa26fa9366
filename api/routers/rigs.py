"""``GET /v1/rigs``: the bundled rigs and the parameters each estimates. ``POST /v1/rigs/parse``:
a rig YAML file → the rig config object the other requests take inline (in a worker, with the
request's deadline: a YAML document can be built to cost seconds)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Request

from excite.rig.config import bundled_rigs

from ..auth import Anyone
from ..context import Ctx
from ..schemas import RigParsed, RigsResponse, RigYaml
from ..scoring import resolve_rig, rig_summary, rig_yaml_task
from .common import AUTH, BODY

router = APIRouter(prefix="/v1", tags=["rigs"])


@router.get("/rigs", response_model=RigsResponse, responses=AUTH, summary="Bundled rigs")
def rigs(who: Anyone) -> Any:
    return {"rigs": [rig_summary(resolve_rig(name)) for name in bundled_rigs()]}


@router.post("/rigs/parse", response_model=RigParsed, responses=BODY,
             summary="Read a rig YAML file: the config object to send as `rig`, and its parameters")
def parse_rig(body: RigYaml, request: Request, ctx: Ctx, who: Anyone) -> Any:
    """For clients that cannot read YAML (the page): the file's mapping, checked as a rig.
    Anchors and aliases are refused, and so are documents nested or sized beyond any rig."""
    return ctx.run(request, who, rig_yaml_task, body.yaml)
