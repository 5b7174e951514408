"""The coordination server as an ASGI app: `create_app(config)` and serve it with uvicorn."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from typing import Any

import aiohttp
from fastapi import FastAPI, Request

from crowdteleop.coord import api_admin, api_internal, api_pairing, api_sessions, pages
from crowdteleop.coord.config import CoordConfig
from crowdteleop.coord.db import make_engine, migrate
from crowdteleop.coord.errors import BodyLimitMiddleware, install_error_handlers
from crowdteleop.coord.headers import SecurityHeadersMiddleware
from crowdteleop.coord.launcher import Launcher, LocalProcessLauncher
from crowdteleop.coord.private import prepare_data_dir
from crowdteleop.coord.reaper import run_reaper
from crowdteleop.coord.security import FailureLimiter
from crowdteleop.coord.service import Coordinator
from crowdteleop.coord.session_keys import SESSION_SECRET_FILE, SessionKeys
from crowdteleop.coord.store import Store
from crowdteleop.web import qr

log = logging.getLogger(__name__)


def create_app(config: CoordConfig, launcher: Launcher | None = None) -> FastAPI:
    """Everything server-wide lives on `app.state`, built and torn down by the lifespan."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        prepare_data_dir(config.data_dir)  # 0700, before the database file is made in it
        keys = SessionKeys.load_or_create(config.data_dir / "state" / SESSION_SECRET_FILE)
        await migrate(config.database_url)
        store = Store(make_engine(config.database_url))
        chosen = launcher or LocalProcessLauncher(
            config.data_dir / "sessions", start_timeout_s=config.teleop_start_timeout_s
        )
        coordinator = Coordinator(config, store, chosen, keys)
        await coordinator.start()
        app.state.coordinator = coordinator
        app.state.pair_limiter = FailureLimiter(config.pair_failures_per_minute, 60.0)
        app.state.http = aiohttp.ClientSession()
        reaper = asyncio.create_task(run_reaper(coordinator), name="reaper")
        try:
            yield
        finally:
            reaper.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await reaper
            await coordinator.close()
            await app.state.http.close()
            await store.close()

    app = FastAPI(
        title="crowdteleop coordination server",
        version="1",
        description="Workers join, queue for a dedicated teleop server, pair a phone, and "
        "teleoperate; see docs/coordination.md.",
        lifespan=lifespan,
        openapi_url="/openapi.json" if config.api_docs else None,
        docs_url="/docs" if config.api_docs else None,
        redoc_url="/redoc" if config.api_docs else None,
    )
    app.add_middleware(BodyLimitMiddleware, max_bytes=config.max_body_bytes)
    # Outermost, so even the body limit's 413 carries the headers.
    docs_pages = ("/docs", "/docs/oauth2-redirect", "/redoc") if config.api_docs else ()
    app.add_middleware(SecurityHeadersMiddleware, docs_paths=docs_pages)
    install_error_handlers(app)
    app.include_router(api_sessions.router)
    app.include_router(api_pairing.router)
    app.include_router(api_admin.router)
    app.include_router(api_internal.router)
    app.include_router(pages.router)
    _include_web_routers(app)
    app.include_router(qr.router)
    app.mount("/static", pages.StaticDirectory(pages.STATIC), name="static")

    @app.get("/health", tags=["server"])
    async def health(request: Request) -> dict[str, Any]:
        coordinator: Coordinator = request.app.state.coordinator
        spares = sum(len(ready) for ready in coordinator.spares.ready.values())
        return {
            "status": "ok",
            "capacity": config.capacity,
            "busy": len(coordinator.pool.slots),
            "spares": spares,
        }

    return app


def _include_web_routers(app: FastAPI) -> None:
    """Routes the web front end adds (crowdteleop/web, e.g. /qr.svg), when it is installed."""
    try:
        from crowdteleop.web.qr import router as qr_router
    except ImportError as exc:
        log.info("no QR code route: %s", exc)
        return
    app.include_router(qr_router)
