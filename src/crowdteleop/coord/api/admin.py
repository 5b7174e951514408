"""Admin endpoints (admin bearer token): the overview with its figures (demonstrations per
hour, completion times per worker and interface), the charts of the last hours, and a
privileged door into a session."""

from __future__ import annotations

import statistics
import time
from collections import defaultdict
from collections.abc import Callable, Iterable
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Query

from crowdteleop.coord.api import views
from crowdteleop.coord.api.deps import (
    CoordinatorDep,
    EpisodesDep,
    HistoryDep,
    MetricsDep,
    SessionId,
    SignalingDep,
    WorkersDep,
    require_admin,
)
from crowdteleop.coord.api.schemas import (
    AdminCharts,
    AdminOverview,
    ChartBin,
    DurationSummary,
    EpisodeView,
    ErrorBody,
    HourCount,
    ScoreBin,
    SessionSummary,
    SessionView,
    TeleopAccess,
    TeleopServerView,
)
from crowdteleop.coord.db.tables import Episode, Session
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.service.coordinator import Coordinator
from crowdteleop.coord.service.workers import Workers
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
async def overview(
    coordinator: CoordinatorDep, episodes: EpisodesDep, metrics: MetricsDep
) -> AdminOverview:
    """Live sessions, the queue, the teleop servers, and the last day's demonstrations."""
    now = time.time()
    live = await coordinator.live_sessions()
    positions = await coordinator.queue_positions()
    summaries = [_summary(s, now, positions.get(s.id, (None, 0))[0]) for s in live]
    servers = [
        TeleopServerView(
            session_id=server.session_id,
            url=server.url,
            pid=server.pid,
            alive=server.alive,
            started_at=server.started_at,
        )
        for server in coordinator.servers()
    ]
    recorded = await episodes.all()
    return AdminOverview(
        now=now,
        capacity=coordinator.capacity,
        sessions=[s for s in summaries if s.state != "queued"],
        queue=[s for s in summaries if s.state == "queued"],
        teleop_servers=servers,
        demos_per_hour=per_hour([e for e in recorded if e.created_at >= now - 86400], now),
        completion_time_per_worker=completion_times(recorded, lambda e: e.worker_id),
        completion_time_per_interface=completion_times(recorded, lambda e: e.interface),
        totals=await episodes.totals(),
        refusals=metrics.refusal_counts(),
        restarts=int(sum(metrics.restarts_by_cause().values())),
    )


@router.get("/charts", response_model=AdminCharts)
async def charts(
    history: HistoryDep,
    hours: Annotated[float, Query(gt=0, le=168, description="how far back")] = 24,
    bin_s: Annotated[float, Query(ge=60, le=86400, description="each bin's length")] = 3600,
) -> AdminCharts:
    """Demonstrations, queue length and wait, live sessions, latency per bin, and the quality
    scores' distribution, over the last `hours` (from the database: no sampling)."""
    if hours * 3600 / bin_s > 2000:
        raise ApiError(422, "invalid_request", "at most 2000 bins: a longer bin_s, or fewer hours")
    drawn = await history.charts(hours, bin_s)
    return AdminCharts(
        now_s=drawn.now_s,
        bin_s=drawn.bin_s,
        bins=[ChartBin.model_validate(b, from_attributes=True) for b in drawn.bins],
        scores=[ScoreBin.model_validate(b, from_attributes=True) for b in drawn.scores],
        unscored=drawn.unscored,
    )


async def _existing(coordinator: Coordinator, session_id: str) -> Session:
    session = await coordinator.session(session_id)
    if session is None:
        raise ApiError(404, "not_found", "no such session")
    return session


async def _view(coordinator: Coordinator, workers: Workers, session: Session) -> SessionView:
    worker = await workers.worker(session.worker_id)
    return await views.session_view(coordinator, session, worker)


@router.get("/sessions/{session_id}", response_model=SessionView)
async def session_view(
    session_id: SessionId, coordinator: CoordinatorDep, workers: WorkersDep
) -> SessionView:
    """Any session as its worker sees it."""
    return await _view(coordinator, workers, await _existing(coordinator, session_id))


@router.get("/sessions/{session_id}/episodes", response_model=list[EpisodeView])
async def session_episodes(
    session_id: SessionId, coordinator: CoordinatorDep, episodes: EpisodesDep
) -> list[EpisodeView]:
    """The episodes a session's teleop server reported, oldest first."""
    await _existing(coordinator, session_id)
    return [
        EpisodeView.model_validate(episode, from_attributes=True)
        for episode in await episodes.of_session(session_id)
    ]


@router.get("/sessions/{session_id}/teleop", response_model=TeleopAccess)
async def teleop_access(
    session_id: SessionId, coordinator: CoordinatorDep, signaling: SignalingDep
) -> TeleopAccess:
    """The session's teleop server URL and tokens, to attach a privileged bot (tests, demos)."""
    door = signaling.door(await _existing(coordinator, session_id))
    return TeleopAccess(url=door.url, token=door.token, admin_token=door.admin_token)


@router.post("/sessions/{session_id}/end", response_model=SessionView)
async def end_session(
    session_id: SessionId, coordinator: CoordinatorDep, workers: WorkersDep
) -> SessionView:
    """End a session by hand (reason 'error'); the slot goes to the next in line."""
    await _existing(coordinator, session_id)
    await coordinator.end(session_id, "error", error="ended by an admin")
    return await _view(coordinator, workers, await _existing(coordinator, session_id))


# --- the overview's figures -------------------------------------------------------------------

HOUR = 3600.0


def per_hour(episodes: Iterable[Episode], now: float, hours: int = 24) -> list[HourCount]:
    """Episodes and successes in each of the last `hours` clock hours, oldest first."""
    current = now - now % HOUR
    first = current - (hours - 1) * HOUR
    counts = {first + i * HOUR: [0, 0] for i in range(hours)}
    for episode in episodes:
        bucket = episode.created_at - episode.created_at % HOUR
        if bucket in counts:
            counts[bucket][0] += 1
            counts[bucket][1] += episode.outcome == "success"
    return [HourCount(hour_start=h, episodes=e, successes=s) for h, (e, s) in counts.items()]


def completion_times(
    episodes: Iterable[Episode], key: Callable[[Episode], str | None]
) -> list[DurationSummary]:
    """Per key: how long successful episodes took (the paper's completion time)."""
    groups: dict[str, list[Episode]] = defaultdict(list)
    for episode in episodes:
        groups[key(episode) or "unknown"].append(episode)
    summaries = []
    for name, group in sorted(groups.items()):
        times = [e.duration_s for e in group if e.outcome == "success"]
        summaries.append(
            DurationSummary(
                key=name,
                successes=len(times),
                episodes=len(group),
                mean_s=round(statistics.fmean(times), 2) if times else None,
                median_s=round(statistics.median(times), 2) if times else None,
                min_s=round(min(times), 2) if times else None,
                max_s=round(max(times), 2) if times else None,
            )
        )
    return summaries
