"""``GET /v1/rigs``: the bundled rigs and the parameters each estimates."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from excite.rig import bundled_rigs

from ..schemas import RigsResponse
from ..scoring import resolve_rig

router = APIRouter(prefix="/v1", tags=["rigs"])


@router.get("/rigs", response_model=RigsResponse, summary="Bundled rigs")
def rigs() -> Any:
    out = []
    for name in bundled_rigs():
        rig = resolve_rig(name)
        out.append({"name": name, "description": rig.config.description,
                    "keyframe_rate_hz": rig.keyframe_rate_hz,
                    "sensors": [{"name": s.name, "kind": s.kind, "rate_hz": s.rate_hz}
                                for s in rig.config.sensors],
                    "parameters": [{"name": c.name, "unit": c.unit, "target": c.target}
                                   for c in rig.scored]})
    return {"rigs": out}
