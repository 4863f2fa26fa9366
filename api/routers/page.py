"""``GET /``: the planners' page (static files shipped in ``api/static``; no build step, no CDN);
the files of ``/docs`` (Swagger UI from the ``swagger-ui-bundle`` package)."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

STATIC_DIR = Path(__file__).resolve().parent.parent / "static"

router = APIRouter(include_in_schema=False)


@router.get("/")
def index() -> FileResponse:
    return FileResponse(STATIC_DIR / "index.html", media_type="text/html; charset=utf-8")


def static_files() -> StaticFiles:
    """The page's script and style sheet, served under ``/static``."""
    return StaticFiles(directory=STATIC_DIR)


def docs_files() -> StaticFiles:
    """Swagger UI's script and style sheet (the ``swagger-ui-bundle`` package), under ``/docs/static``."""
    import swagger_ui_bundle

    return StaticFiles(directory=swagger_ui_bundle.swagger_ui_path)
