"""The coordination server as an ASGI app: `create_app(config)` and serve it with uvicorn."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import AsyncIterator
from typing import Any

import aiohttp
from fastapi import Depends, FastAPI, Request
from fastapi.responses import Response

from crowdteleop.coord.api import admin, internal, pages, pairing, regions, sessions
from crowdteleop.coord.api.deps import require_admin
from crowdteleop.coord.db.engine import make_engine, migrate
from crowdteleop.coord.db.store import Store
from crowdteleop.coord.fleet.cluster import follow_cluster
from crowdteleop.coord.fleet.launcher import Launcher, LocalProcessLauncher
from crowdteleop.coord.guard.errors import BodyLimitMiddleware, install_error_handlers
from crowdteleop.coord.guard.headers import SecurityHeadersMiddleware
from crowdteleop.coord.guard.http_limits import BodyTimeoutMiddleware
from crowdteleop.coord.guard.private import prepare_data_dir
from crowdteleop.coord.guard.session_keys import SESSION_SECRET_FILE, SessionKeys
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.coordinator import Coordinator
from crowdteleop.coord.service.guards import Guards
from crowdteleop.coord.service.liveness import run_liveness
from crowdteleop.coord.service.metrics import CoordMetrics
from crowdteleop.coord.service.reaper import run_reaper
from crowdteleop.coord.service.spools import run_spool_sweeper
from crowdteleop.web import qr

log = logging.getLogger(__name__)


def _launcher(config: CoordConfig) -> Launcher:
    if config.ray is not None:
        from crowdteleop.coord.fleet.ray_launcher import RayLauncher

        return RayLauncher(config.ray, config.teleop_host)
    return LocalProcessLauncher(
        config.data_dir / "sessions",
        start_timeout_s=config.teleop_start_timeout_s,
        host=config.teleop_host,
    )


def create_app(config: CoordConfig, launcher: Launcher | None = None) -> FastAPI:
    """Everything server-wide lives on `app.state`, built and torn down by the lifespan."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        prepare_data_dir(config.data_dir)  # 0700, before the database file is made in it
        keys = SessionKeys.load_or_create(config.data_dir / "state" / SESSION_SECRET_FILE)
        await migrate(config.database_url)
        store = Store(make_engine(config.database_url))
        chosen = launcher or _launcher(config)
        metrics = CoordMetrics()
        coordinator = Coordinator(config, store, chosen, keys, metrics)
        await follow_cluster(coordinator, admit=False)  # a cluster's room, before admitting
        await coordinator.start()
        app.state.coordinator = coordinator
        app.state.guards = Guards.of(config, metrics, store.transactions)
        app.state.http = aiohttp.ClientSession()
        watchers = [
            asyncio.create_task(run_reaper(coordinator), name="reaper"),
            asyncio.create_task(run_liveness(coordinator), name="liveness"),
            asyncio.create_task(run_spool_sweeper(coordinator), name="spools"),
        ]
        try:
            yield
        finally:
            for watcher in watchers:
                watcher.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await watcher
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
    app.add_middleware(BodyTimeoutMiddleware, timeout_s=config.body_timeout_s)  # bounds its read
    # Outermost, so even the body limit's 413 carries the headers.
    docs_pages = ("/docs", "/docs/oauth2-redirect", "/redoc") if config.api_docs else ()
    app.add_middleware(
        SecurityHeadersMiddleware, docs_paths=docs_pages, connect_origins=config.region_origins()
    )
    install_error_handlers(app)
    app.include_router(sessions.router)
    app.include_router(regions.router)
    app.include_router(pairing.router)
    app.include_router(admin.router)
    app.include_router(internal.router)
    app.include_router(pages.router)
    _include_web_routers(app)
    app.include_router(qr.router)
    app.mount("/static", pages.StaticDirectory(pages.STATIC), name="static")

    @app.get("/health", tags=["server"])
    async def health(request: Request) -> dict[str, Any]:
        coordinator: Coordinator = request.app.state.coordinator
        spares = len(coordinator.spares.handles)
        return {
            "status": "ok",
            "capacity": coordinator.pool.capacity,
            "busy": len(coordinator.pool.slots),
            "spares": spares,
        }

    @app.get("/metrics", tags=["server"], dependencies=[Depends(require_admin)])
    async def metrics(request: Request) -> Response:
        """Prometheus's text format (admin token: `bearer_token` in the scrape config)."""
        coordinator: Coordinator = request.app.state.coordinator
        metrics = coordinator.metrics
        live = await coordinator.store.live_sessions()
        for state in ("queued", "starting", "ready"):
            metrics.sessions.labels(state=state).set(sum(s.state == state for s in live))
        metrics.capacity.set(coordinator.pool.capacity)
        metrics.spares.set(len(coordinator.spares.handles))
        recent = await coordinator.store.episodes_since(time.time() - 3600)
        metrics.demos_last_hour.set(sum(e.outcome == "success" for e in recent))
        metrics.spool_pending.set(sum(s.spool_pending for s in coordinator.pool.slots.values()))
        return Response(metrics.exposition(), media_type="text/plain; version=0.0.4")

    return app


def _include_web_routers(app: FastAPI) -> None:
    """Routes the web front end adds (crowdteleop/web, e.g. /qr.svg), when it is installed."""
    try:
        from crowdteleop.web.qr import router as qr_router
    except ImportError as exc:
        log.info("no QR code route: %s", exc)
        return
    app.include_router(qr_router)
