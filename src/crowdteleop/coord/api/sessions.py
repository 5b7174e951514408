"""Workers: join, get a session, keep it alive, leave, and signal WebRTC to its server."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Body, Path, Query

from crowdteleop.coord.api.deps import (
    ClientDep,
    CompletionDep,
    ConfigDep,
    CoordinatorDep,
    GuardsDep,
    OwnedSession,
    SessionId,
    SignalingDep,
    WorkerDep,
    WorkersDep,
    owned,
    token_of,
    worker_for,
)
from crowdteleop.coord.api.deps import Credentials as CredentialsDep
from crowdteleop.coord.api.schemas import (
    CampaignView,
    ErrorBody,
    HeartbeatRequest,
    JoinRequest,
    JoinResponse,
    OfferBody,
    RegionView,
    SessionView,
)
from crowdteleop.coord.api.views import preparation_view, session_view
from crowdteleop.coord.db.tables import Worker
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.service.campaign import NAME_PATTERN, CampaignConfig
from crowdteleop.coord.service.coordinator import Coordinator
from crowdteleop.teleop.messages import OfferAnswer

ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorBody} for code in (401, 403, 404, 409, 422, 429, 503)
}
router = APIRouter(prefix="/api", tags=["workers"], responses=ERRORS)


def campaign_view(campaign: CampaignConfig) -> CampaignView:
    return CampaignView(
        name=campaign.name,
        title=campaign.title,
        instructions=campaign.instructions,
        tasks=campaign.tasks,
        interfaces=campaign.interfaces,
        demos_required=campaign.demos_required,
        time_limit_s=campaign.time_limit_s,
        regions=[RegionView(name=r.name, url=str(r.url)) for r in campaign.regions],
    )


@router.get("/campaigns/{name}", response_model=CampaignView)
async def campaign(
    name: Annotated[str, Path(pattern=NAME_PATTERN)],
    config: ConfigDep,
    coordinator: CoordinatorDep,
) -> CampaignView:
    """What the join page shows before anyone agrees: the task, how many demonstrations and
    how long it takes, and whether a robot is ready or being prepared. `default` is the
    campaign a link without `campaign=` joins."""
    chosen = config.campaign(name)
    if chosen is None and name == "default":
        chosen = config.default_campaign
    if chosen is None:
        raise ApiError(404, "unknown_campaign", f"no campaign named {name!r}")
    typical = await coordinator.typical_session_s()
    view = campaign_view(chosen)
    return view.model_copy(
        update={
            "typical_session_s": round(typical) if typical is not None else None,
            "region": config.region,
            "robot": preparation_view(await coordinator.preparation.newcomer_wait()),
        }
    )


@router.post("/join", response_model=JoinResponse)
async def join(
    body: JoinRequest, workers: WorkersDep, guards: GuardsDep, client: ClientDep
) -> JoinResponse:
    """Register (or recognise) the worker a join link names; returns their bearer token.

    Joins are rate limited per address and in total (429). A campaign may refuse links
    without study ids (403). A study id whose session is open in another browser is refused
    (409 `in_use`) unless this browser presents its earlier token or asks to take over."""
    link = workers.check_link(body.campaign, body.params, body.region_rtts_ms)
    guards.admit_join(client)
    worker, token = await workers.join(link, body.worker_token, body.take_over)
    return JoinResponse(
        worker_id=worker.id,
        worker_token=token,
        source=link.who.source,
        campaign=campaign_view(link.campaign),
    )


@router.post("/sessions", response_model=SessionView)
async def create_session(
    worker: WorkerDep, workers: WorkersDep, coordinator: CoordinatorDep, client: ClientDep
) -> SessionView:
    """The worker's live session, or a new one: ready soon, or queued when the pool is full.
    A new one is refused when its network has too many open (429), the queue is full or the
    wait too long (503, with Retry-After), or the worker was blocked (403)."""
    workers.check_not_blocked(worker)
    campaign = workers.campaign_of(worker)
    session = await coordinator.create_session(worker, campaign, client)
    return await session_view(coordinator, session, worker)


@router.get("/sessions/{session_id}", response_model=SessionView)
async def get_session(
    session: OwnedSession, worker: WorkerDep, coordinator: CoordinatorDep, held: CompletionDep
) -> SessionView:
    """The session; where its code waits for review, how many are accepted and awaiting."""
    return await session_view(coordinator, session, worker, await held.progress(session))


@router.post("/sessions/{session_id}/heartbeat", response_model=SessionView)
async def heartbeat(
    session: OwnedSession,
    worker: WorkerDep,
    coordinator: CoordinatorDep,
    held: CompletionDep,
    body: Annotated[HeartbeatRequest | None, Body()] = None,
) -> SessionView:
    """Keeps the session (or its place in the queue); silence ends it as abandoned."""
    await coordinator.heartbeat(session, body.interface if body else None)
    refreshed = await coordinator.session(session.id) or session
    return await session_view(coordinator, refreshed, worker, await held.progress(refreshed))


@router.post("/sessions/{session_id}/leave", response_model=SessionView)
async def leave(
    session_id: SessionId,
    workers: WorkersDep,
    coordinator: CoordinatorDep,
    credentials: CredentialsDep,
    token: Annotated[
        str | None, Query(max_length=512, description="for sendBeacon, which sets no headers")
    ] = None,
) -> SessionView:
    """End the session now and free its slot (the page calls this on pagehide)."""
    worker = await worker_for(workers, token_of(credentials) or token)
    session = await owned(coordinator, session_id, worker)
    return await _end(coordinator, session.id, worker)


@router.delete("/sessions/{session_id}", response_model=SessionView)
async def delete_session(
    session: OwnedSession, worker: WorkerDep, coordinator: CoordinatorDep
) -> SessionView:
    return await _end(coordinator, session.id, worker)


async def _end(coordinator: Coordinator, session_id: str, worker: Worker) -> SessionView:
    await coordinator.end(session_id, "left")
    session = await coordinator.session(session_id)
    assert session is not None
    return await session_view(coordinator, session, worker)


@router.post("/sessions/{session_id}/offer", response_model=OfferAnswer)
async def offer(body: OfferBody, session: OwnedSession, signaling: SignalingDep) -> OfferAnswer:
    """WebRTC offer for the session's teleop server (role worker); 409 until it is ready."""
    return await signaling.offer(session, body.sdp, "worker")
