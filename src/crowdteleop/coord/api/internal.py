"""What teleop servers tell the coordinator: each stored episode (bearer = report token)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter

from crowdteleop.coord.api.deps import Credentials, EpisodesDep, token_of
from crowdteleop.coord.api.schemas import ErrorBody
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.teleop.messages import EpisodeAck, EpisodeReport

ERRORS: dict[int | str, dict[str, Any]] = {code: {"model": ErrorBody} for code in (401, 403, 422)}
router = APIRouter(prefix="/internal", tags=["internal"], responses=ERRORS)


@router.post("/episodes", response_model=EpisodeAck)
async def episode_report(
    report: EpisodeReport, episodes: EpisodesDep, credentials: Credentials
) -> EpisodeAck:
    """Idempotent by episode_id; successes count toward the session's demos_required."""
    token = token_of(credentials)
    session = await episodes.reporting_session(token) if token else None
    if session is None:
        raise ApiError(401, "unauthorized", "a session's report token is required")
    if report.session_id != session.id:
        raise ApiError(403, "wrong_session", "this token reports for another session")
    recorded = await episodes.record(session, report)
    return EpisodeAck(
        episode_id=report.episode_id,
        duplicate=not recorded.new,
        demos_done=recorded.demos_done,
        demos_required=session.demos_required,
        completed=recorded.completed,
        feedback=recorded.feedback,
    )
