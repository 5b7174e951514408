"""The browser pages (written in crowdteleop/web/static), the protocol schema and the schema of
the answers the pages check."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi import APIRouter, Request
from fastapi.responses import FileResponse, HTMLResponse, RedirectResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.exceptions import HTTPException
from starlette.types import Scope

STATIC = Path(__file__).resolve().parents[2] / "web" / "static"
PAGES = ("join", "teleop", "phone", "admin", "workers", "review")
router = APIRouter(include_in_schema=False)

MISSING = """<!doctype html><meta charset="utf-8"><title>Page missing</title>
<h1>404: the {name} page is not installed</h1>
<p>This coordination server has no <code>web/static/{name}.html</code>.</p>"""


def _page(name: str) -> Response:
    path = STATIC / f"{name}.html"
    if not path.is_file():
        return HTMLResponse(MISSING.format(name=name), status_code=404)
    return FileResponse(path, media_type="text/html", headers={"Cache-Control": "no-cache"})


def _register(name: str) -> None:
    async def page() -> Response:
        return _page(name)

    page.__name__ = f"{name}_page"
    router.add_api_route(f"/{name}", page, methods=["GET"])


for _name in PAGES:
    _register(_name)


@router.get("/")
async def root(request: Request) -> RedirectResponse:
    query = request.url.query
    return RedirectResponse(f"/join?{query}" if query else "/join", status_code=307)


@router.get("/protocol.json")
async def protocol() -> dict[str, Any]:
    from crowdteleop.teleop.protocol import json_schema

    return json_schema()


@router.get("/views.json")
async def views() -> dict[str, Any]:
    """The JSON Schema of the coordinator's answers the pages check (`web/static/api.js`)."""
    from crowdteleop.coord.api.schemas import page_views_schema

    return page_views_schema()


class StaticDirectory(StaticFiles):
    """StaticFiles that answers 404 (not 500) while the folder does not exist yet."""

    def __init__(self, directory: Path) -> None:
        super().__init__(directory=directory, check_dir=False)
        self.folder = directory

    async def check_config(self) -> None:
        if self.folder.is_dir():
            await super().check_config()

    async def get_response(self, path: str, scope: Scope) -> Response:
        if not self.folder.is_dir():
            raise HTTPException(404, "no static files are installed")
        return await super().get_response(path, scope)
