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
    response.headers["Timing-Allow-Origin"] = "*"  # the pages read the network's own timing
    response.headers["Cache-Control"] = "no-store"
    occupancy = await coordinator.occupancy()  # from memory between reads: a probe's cost
    return PingView(
        region=config.region,
        capacity=occupancy.capacity,
        free_slots=occupancy.free_slots,
        queued=occupancy.queued,
    )
