"""``GET /``: the dashboard, one static page (``api/dashboard/``) that polls the ``/v1`` API from
the browser. Everything it needs ships with the package: no CDN, so it works offline."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

ASSETS = Path(__file__).resolve().parent.parent / "dashboard"

router = APIRouter(include_in_schema=False)


@router.get("/")
def dashboard() -> FileResponse:
    return FileResponse(ASSETS / "index.html", headers={"Cache-Control": "no-cache"})


def static_files() -> StaticFiles:
    """The page's scripts and styles, mounted at ``/dashboard``."""
    return StaticFiles(directory=ASSETS)
