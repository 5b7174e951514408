"""The server's own endpoints: `/health` for load balancers, `/metrics` for Prometheus."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, Depends
from fastapi.responses import Response

from crowdteleop.coord.api.deps import CoordinatorDep, EpisodesDep, MetricsDep, require_admin

router = APIRouter(tags=["server"])


@router.get("/health")
async def health(coordinator: CoordinatorDep) -> dict[str, Any]:
    return {
        "status": "ok",
        "capacity": coordinator.capacity,
        "busy": len(coordinator.servers()),
        "spares": len(coordinator.spares()),
    }


@router.get("/metrics", dependencies=[Depends(require_admin)])
async def metrics(
    coordinator: CoordinatorDep, episodes: EpisodesDep, metrics: MetricsDep
) -> Response:
    """Prometheus's text format (admin token: `bearer_token` in the scrape config)."""
    live = await coordinator.live_sessions()
    for state in ("queued", "starting", "ready"):
        metrics.sessions.labels(state=state).set(sum(s.state == state for s in live))
    metrics.capacity.set(coordinator.capacity)
    metrics.spares.set(len(coordinator.spares()))
    recent = await episodes.since(time.time() - 3600)
    metrics.demos_last_hour.set(sum(e.outcome == "success" for e in recent))
    servers = coordinator.servers()
    metrics.spool_pending.set(sum(server.spool_pending for server in servers))
    metrics.reports_pending.set(sum(server.reports_pending for server in servers))
    metrics.servers_unable_to_report.set(sum(server.reports_unreachable for server in servers))
    return Response(metrics.exposition(), media_type="text/plain; version=0.0.4")
