"""The coordination server as an ASGI app: `create_app(config)` and serve it with uvicorn."""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator

from fastapi import FastAPI

from crowdteleop.coord.api import (
    admin,
    internal,
    pages,
    pairing,
    regions,
    review,
    server,
    sessions,
    workers,
)
from crowdteleop.coord.db.engine import make_engine, migrate
from crowdteleop.coord.db.store import Store
from crowdteleop.coord.fleet.launcher import Launcher, LocalProcessLauncher
from crowdteleop.coord.guard.errors import install_error_handlers
from crowdteleop.coord.guard.headers import SecurityHeadersMiddleware
from crowdteleop.coord.guard.http_limits import BodyLimitMiddleware, BodyTimeoutMiddleware
from crowdteleop.coord.guard.private import prepare_data_dir
from crowdteleop.coord.guard.session_keys import SESSION_SECRET_FILE, SessionKeys
from crowdteleop.coord.service.completion import Completion
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.coordinator import Coordinator
from crowdteleop.coord.service.episodes import Episodes
from crowdteleop.coord.service.guards import Guards
from crowdteleop.coord.service.history import History
from crowdteleop.coord.service.metrics import CoordMetrics
from crowdteleop.coord.service.pairing import Pairing
from crowdteleop.coord.service.reputation import WorkerRecords
from crowdteleop.coord.service.review import Reviews
from crowdteleop.coord.service.review_video import EpisodeVideos, MediaLinks
from crowdteleop.coord.service.signaling import Signaling
from crowdteleop.coord.service.workers import Workers
from crowdteleop.web import qr


def _launcher(config: CoordConfig) -> Launcher:
    if config.ray is not None:
        from crowdteleop.coord.fleet.ray_launcher import RayLauncher

        launcher = RayLauncher(config.ray, config.teleop_host)
        shared = config.ray.shared_storage or _episode_storage(config) == "s3"
        launcher.check(f"{config.report_base_url}/internal/episodes", episodes_shared=shared)
        return launcher
    return LocalProcessLauncher(
        config.data_dir / "sessions",
        start_timeout_s=config.teleop_start_timeout_s,
        host=config.teleop_host,
    )


def _episode_storage(config: CoordConfig) -> str:
    """Where the teleop servers store episodes ("local" or "s3"): `teleop.recording.storage`."""
    recording = config.teleop.get("recording")
    storage = recording.get("storage") if isinstance(recording, dict) else None
    return str(storage.get("kind", "local")) if isinstance(storage, dict) else "local"


def create_app(config: CoordConfig, launcher: Launcher | None = None) -> FastAPI:
    """Everything server-wide lives on `app.state`, built and torn down by the lifespan: the
    config, the `Coordinator` (which owns the background sweeps), and the services the
    routers call."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        prepare_data_dir(config.data_dir)  # 0700, before the database file is made in it
        keys = SessionKeys.load_or_create(config.data_dir / "state" / SESSION_SECRET_FILE)
        await migrate(config.database_url)
        store = Store(make_engine(config.database_url))
        metrics = CoordMetrics()
        coordinator = Coordinator(config, store, launcher or _launcher(config), keys, metrics)
        await coordinator.start()
        coordinator.start_sweeps()
        signaling = Signaling(keys)
        state = app.state
        state.config, state.metrics, state.coordinator = config, metrics, coordinator
        state.workers = Workers(store, config, metrics)
        state.pairing = Pairing(store, config)
        state.signaling = signaling
        state.guards = Guards.of(config, metrics, store)
        state.history = History(store)
        # The review service's decisions reach the completion hold through its on_decided.
        state.completion = Completion(store, config, coordinator)
        state.worker_records = WorkerRecords(store, coordinator, metrics)
        state.reviews = Reviews(store, config, metrics, on_decided=state.completion.on_decided)
        state.episodes = Episodes(store, config, metrics, state.completion, state.reviews)
        state.review_videos, state.review_links = (
            EpisodeVideos(config),
            MediaLinks(config.admin_token),
        )
        try:
            yield
        finally:
            await coordinator.close()
            await signaling.close()
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
    for router in (sessions, regions, pairing, admin, workers, review, internal, pages, qr, server):
        app.include_router(router.router)
    app.mount("/static", pages.StaticDirectory(pages.STATIC), name="static")
    return app
