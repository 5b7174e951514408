"""Regions: one campaign served from several places, each a coordinator with its own cluster.
The join pages of a campaign's regions time `GET /api/ping` to each and go to the nearest
with a free robot (the region a join lands in is recorded: `coord/service/workers.py`)."""

from __future__ import annotations

from fastapi import APIRouter, Response

from crowdteleop.coord.api.deps import ConfigDep, CoordinatorDep
from crowdteleop.coord.api.schemas import PingView

router = APIRouter(prefix="/api", tags=["regions"])


@router.get("/ping", response_model=PingView)
async def ping(coordinator: CoordinatorDep, config: ConfigDep, response: Response) -> PingView:
    """How free this region is. The join pages of the campaign's other regions time a few of
    these (any origin may ask: it says nothing about anyone) and read the free robots."""
    response.headers["Access-Control-Allow-Origin"] = "*"
    response.headers["Cache-Control"] = "no-store"
    live = await coordinator.live_sessions()
    held = sum(session.state in ("starting", "ready") for session in live)
    capacity = coordinator.capacity
    return PingView(
        region=config.region,
        capacity=capacity,
        free_slots=max(0, capacity - held),
        queued=sum(session.state == "queued" for session in live),
    )
