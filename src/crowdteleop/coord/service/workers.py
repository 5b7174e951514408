"""Workers: who a join link names, into which campaign and region, and which browser holds
their session.

Regions: one campaign served from several places, each a coordinator with its own cluster
(the paper's Oregon-vs-China test). The join page times a few `GET /api/ping` to every region
its campaign lists and goes to the nearest one with a free robot (web/static/region.js). The
region it lands in records the choice with the worker and hands it to the teleop server of
their next session, so every episode says where it was recorded and how far each region was.
"""

from __future__ import annotations

from dataclasses import dataclass

from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Worker
from crowdteleop.coord.db.workers import SessionInUseError, WorkerBlockedError
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.guard.identity import Identity, identify
from crowdteleop.coord.service.campaign import CampaignConfig
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.metrics import CoordMetrics
from crowdteleop.recording.metadata import RegionChoice


@dataclass(frozen=True)
class JoinLink:
    """A join link, checked: where it leads and whom it names."""

    campaign: CampaignConfig
    who: Identity
    params: dict[str, str]  # as the link carried them (kept with the worker)
    region: RegionChoice | None


class Workers:
    def __init__(self, store: Store, config: CoordConfig, metrics: CoordMetrics) -> None:
        self._workers, self._config, self._metrics = store.workers, config, metrics

    def check_link(
        self, campaign_name: str | None, params: dict[str, str], rtts_ms: dict[str, float] | None
    ) -> JoinLink:
        """What a join link says: its campaign (404 if none), who the worker is (422 for
        malformed ids), whether the campaign takes them (403), and the region choice it
        records (422 for round trips to regions the campaign does not list)."""
        campaign = self._config.campaign(campaign_name)
        if campaign is None:
            raise ApiError(404, "unknown_campaign", f"no campaign named {campaign_name!r}")
        who = identify(params)
        if who.source == "anonymous" and not campaign.allow_anonymous:
            self._metrics.refused("anonymous")
            raise ApiError(
                403,
                "study_link_required",
                "this study is open to its participants only: please use the link your study "
                "platform (Prolific or MTurk) gave you",
            )
        try:
            region = region_choice(self._config, campaign, rtts_ms)
        except ApiError:
            self._metrics.refused("unknown_region")
            raise
        return JoinLink(campaign, who, params, region)

    async def join(
        self, link: JoinLink, presented_token: str | None, take_over: bool
    ) -> tuple[Worker, str]:
        """(the worker, their bearer token): the same study id is the same worker. A study id
        whose session is open in another browser is refused (409 `in_use`) unless this browser
        presents its earlier token or asks to take over."""
        who = link.who
        try:
            worker, token, _created = await self._workers.join(
                link.campaign.name,
                who.source,
                who.external_id,
                who.study_id,
                who.external_session,
                link.params,
                presented_token=presented_token,
                take_over=take_over,
            )
        except WorkerBlockedError as exc:
            raise blocked_refusal(self._metrics) from exc
        except SessionInUseError as exc:
            self._metrics.refused("in_use")
            raise ApiError(
                409,
                "in_use",
                "Your session is open in another browser. Continue there, or take it over here "
                "(the other one will stop).",
            ) from exc
        if link.region is not None or worker.region is not None:
            choice = link.region.model_dump() if link.region is not None else None
            await self._workers.set_worker_region(worker.id, choice)
        self._metrics.joins.labels(source=who.source).inc()
        return worker, token

    def check_not_blocked(self, worker: Worker) -> None:
        """Refuse (403 `blocked`) a worker an admin blocked: no new session for them."""
        if worker.blocked_at is not None:
            raise blocked_refusal(self._metrics)

    async def holder(self, token: str) -> tuple[Worker | None, bool]:
        """(the worker a token belongs to, revoked?): a revoked token names its old owner."""
        return await self._workers.token_holder(token)

    async def worker(self, worker_id: str) -> Worker | None:
        return await self._workers.worker(worker_id)

    def campaign_of(self, worker: Worker) -> CampaignConfig:
        """The campaign of the link the worker came by last (the default one if it is gone)."""
        return self._config.campaign(worker.campaign) or self._config.default_campaign


def blocked_refusal(metrics: CoordMetrics) -> ApiError:
    """What a blocked worker is told (the admin's reason stays with the admin), counted."""
    metrics.refused("blocked")
    return ApiError(
        403,
        "blocked",
        "This study no longer accepts your participation. Please return it on your study "
        "platform; if you think this is a mistake, message the researchers there.",
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
