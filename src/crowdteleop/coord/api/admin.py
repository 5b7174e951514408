"""Admin endpoints (admin bearer token): the overview, and a privileged door into a session."""

from __future__ import annotations

import time
from typing import Any

from fastapi import APIRouter, Depends

from crowdteleop.coord.api import views
from crowdteleop.coord.api.deps import CoordinatorDep, SessionId, require_admin
from crowdteleop.coord.api.schemas import (
    AdminOverview,
    EpisodeView,
    ErrorBody,
    SessionSummary,
    SessionView,
    TeleopAccess,
    TeleopServerView,
)
from crowdteleop.coord.api.stats import completion_times, per_hour
from crowdteleop.coord.db.tables import Session
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.recording.metadata import RegionChoice

ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorBody} for code in (401, 404, 409, 422, 429)
}
router = APIRouter(
    prefix="/api/admin", tags=["admin"], dependencies=[Depends(require_admin)], responses=ERRORS
)


def _summary(session: Session, now: float, position: int | None) -> SessionSummary:
    return SessionSummary(
        session_id=session.id,
        worker_id=session.worker_id,
        campaign=session.campaign,
        state=session.state,
        queue_position=position,
        task=session.task,
        robot=session.robot,
        controller=session.controller,
        interface=session.interface,
        demos_done=session.demos_done,
        demos_required=session.demos_required,
        created_at=session.created_at,
        ready_at=session.ready_at,
        last_heartbeat_s_ago=round(now - session.last_heartbeat_at, 1),
        teleop_url=session.teleop_url,
        rtt_ms=_round_trip_here_ms(session),
    )


def _round_trip_here_ms(session: Session) -> float | None:
    """The worker's round trip to this region, as their join page measured it."""
    if session.region is None:
        return None
    choice = RegionChoice.model_validate(session.region)
    return choice.rtts_ms.get(choice.region)


@router.get("/overview", response_model=AdminOverview)
async def overview(coordinator: CoordinatorDep) -> AdminOverview:
    """Live sessions, the queue, the teleop servers, and the last day's demonstrations."""
    now = time.time()
    store = coordinator.store
    live = await store.live_sessions()
    positions = await coordinator.queue_positions()
    summaries = [_summary(s, now, positions.get(s.id, (None, 0))[0]) for s in live]
    servers = []
    for session_id, slot in coordinator.pool.slots.items():
        handle = slot.handle
        servers.append(
            TeleopServerView(
                session_id=session_id,
                url=handle.url if handle else None,
                pid=getattr(handle, "pid", None),
                alive=handle is not None and coordinator.pool.launcher.alive(handle),
                started_at=slot.reserved_at,
            )
        )
    episodes = await store.episodes()
    return AdminOverview(
        now=now,
        capacity=coordinator.pool.capacity,
        sessions=[s for s in summaries if s.state != "queued"],
        queue=[s for s in summaries if s.state == "queued"],
        teleop_servers=servers,
        demos_per_hour=per_hour([e for e in episodes if e.created_at >= now - 86400], now),
        completion_time_per_worker=completion_times(episodes, lambda e: e.worker_id),
        completion_time_per_interface=completion_times(episodes, lambda e: e.interface),
        totals=await store.totals(),
        refusals=coordinator.metrics.refusal_counts(),
        restarts=int(sum(coordinator.metrics.restarts_by_cause().values())),
    )


@router.get("/sessions/{session_id}", response_model=SessionView)
async def session_view(session_id: SessionId, coordinator: CoordinatorDep) -> SessionView:
    """Any session as its worker sees it."""
    session = await coordinator.store.session(session_id)
    if session is None:
        raise ApiError(404, "not_found", "no such session")
    return await views.session_view(coordinator, session)


@router.get("/sessions/{session_id}/episodes", response_model=list[EpisodeView])
async def session_episodes(session_id: SessionId, coordinator: CoordinatorDep) -> list[EpisodeView]:
    """The episodes a session's teleop server reported, oldest first."""
    if await coordinator.store.session(session_id) is None:
        raise ApiError(404, "not_found", "no such session")
    return [
        EpisodeView.model_validate(episode, from_attributes=True)
        for episode in await coordinator.store.episodes(session_id)
    ]


@router.get("/sessions/{session_id}/teleop", response_model=TeleopAccess)
async def teleop_access(session_id: SessionId, coordinator: CoordinatorDep) -> TeleopAccess:
    """The session's teleop server URL and tokens, to attach a privileged bot (tests, demos)."""
    session = await coordinator.store.session(session_id)
    if session is None:
        raise ApiError(404, "not_found", "no such session")
    if session.state != "ready" or not session.teleop_url:
        raise ApiError(409, "not_ready", f"the session is {session.state}, not ready")
    keys = coordinator.keys
    return TeleopAccess(
        url=session.teleop_url,
        token=keys.teleop_token(session.id),
        admin_token=keys.teleop_admin_token(session.id),
    )


@router.post("/sessions/{session_id}/end", response_model=SessionView)
async def end_session(session_id: SessionId, coordinator: CoordinatorDep) -> SessionView:
    """End a session by hand (reason 'error'); the slot goes to the next in line."""
    session = await coordinator.store.session(session_id)
    if session is None:
        raise ApiError(404, "not_found", "no such session")
    await coordinator.end(session_id, "error", error="ended by an admin")
    ended = await coordinator.store.session(session_id)
    assert ended is not None
    return await views.session_view(coordinator, ended)
