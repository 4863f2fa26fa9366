"""``GET /``: the planners' page (static files shipped in ``api/static``; no build step, no CDN);
``/openapi.json`` and ``/docs`` (Swagger UI, its files from the ``swagger-ui-bundle`` package)."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, FastAPI, Security
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from ..auth import authorize

STATIC_DIR = Path(__file__).resolve().parent.parent / "static"

router = APIRouter(include_in_schema=False)


@router.get("/")
def index() -> FileResponse:
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html; charset=utf-8")


def add_docs(app: FastAPI, access: str) -> None:
    """``/openapi.json`` and ``/docs`` for everyone (``public``), any key (``authenticated``) or no
    one (``off``)."""
    if access == "off":
        return
    import swagger_ui_bundle

    deps = [] if access == "public" else [Security(authorize)]

    async def openapi_json() -> JSONResponse:
        return JSONResponse(app.openapi())

    async def swagger() -> FileResponse:
        return FileResponse(STATIC_DIR / "docs.html", media_type="text/html; charset=utf-8")

    app.add_api_route("/openapi.json", openapi_json, include_in_schema=False, dependencies=deps)
    app.add_api_route("/docs", swagger, include_in_schema=False, dependencies=deps)
    app.mount("/docs/static", StaticFiles(directory=swagger_ui_bundle.swagger_ui_path), name="docs-static")
