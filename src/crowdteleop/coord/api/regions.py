"""Regions: one campaign served from several places, each a coordinator with its own cluster
(the paper's Oregon-vs-China test).

The join page times a few `GET /api/ping` to every region its campaign lists and goes to the
nearest one with a free robot (web/static/region.js). The region it lands in records the choice
with the worker and hands it to the teleop server of their next session, so every episode says
where it was recorded and how far each region was.
"""

from __future__ import annotations

from fastapi import APIRouter, Response

from crowdteleop.coord.api.deps import CoordinatorDep
from crowdteleop.coord.api.schemas import PingView
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.service.campaign import CampaignConfig
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.recording.metadata import RegionChoice

router = APIRouter(prefix="/api", tags=["regions"])


@router.get("/ping", response_model=PingView)
async def ping(coordinator: CoordinatorDep, response: Response) -> PingView:
    """How free this region is. The join pages of the campaign's other regions time a few of
    these (any origin may ask: it says nothing about anyone) and read the free robots."""
    response.headers["Access-Control-Allow-Origin"] = "*"
    response.headers["Cache-Control"] = "no-store"
    live = await coordinator.store.live_sessions()
    held = sum(session.state in ("starting", "ready") for session in live)
    capacity = coordinator.pool.capacity
    return PingView(
        region=coordinator.config.region,
        capacity=capacity,
        free_slots=max(0, capacity - held),
        queued=sum(session.state == "queued" for session in live),
    )


def region_choice(
    config: CoordConfig, campaign: CampaignConfig, rtts_ms: dict[str, float] | None
) -> RegionChoice | None:
    """What a join into `campaign` here records: this region and the round trips the page
    measured (none when the campaign lists no regions). Round trips to regions the campaign
    does not list are refused (422), so a dataset's regions are always the campaign's."""
    if not campaign.regions or config.region is None:
        return None
    listed = {region.name for region in campaign.regions}
    unknown = sorted(set(rtts_ms or {}) - listed)
    if unknown:
        raise ApiError(
            422,
            "unknown_region",
            f"round trips to {unknown}: campaign {campaign.name!r} lists regions {sorted(listed)}",
        )
    return RegionChoice(region=config.region, rtts_ms=rtts_ms or {})
