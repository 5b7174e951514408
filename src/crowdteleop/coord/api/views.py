"""What a worker's page is told about its session (`SessionView`)."""

from __future__ import annotations

import time

from crowdteleop.coord.api.schemas import RobotPreparation, SessionView
from crowdteleop.coord.db.tables import Session, Worker
from crowdteleop.coord.service.completion import ReviewProgress
from crowdteleop.coord.service.coordinator import Coordinator
from crowdteleop.coord.service.preparing import Preparing
from crowdteleop.tasks import get_task

PROLIFIC_COMPLETE = "https://app.prolific.com/submissions/complete?cc="


async def session_view(
    coordinator: Coordinator,
    session: Session,
    worker: Worker | None,
    progress: ReviewProgress | None = None,
) -> SessionView:
    """The session as its worker's page sees it (`worker`: whose it is, for the study's way
    back; None if unknown; `progress`: toward a completion code held for review)."""
    position, eta = None, None
    if session.state == "queued":
        position, eta = (await coordinator.queue_positions()).get(session.id, (None, None))
    redirect = None
    if session.completion_code and worker is not None and worker.source == "prolific":
        redirect = PROLIFIC_COMPLETE + session.completion_code
    time_left = None
    if session.state == "ready" and session.ready_at is not None:
        time_left = round(max(0.0, session.ready_at + session.time_limit_s - time.time()), 1)
    return SessionView(
        session_id=session.id,
        state=session.state,
        queue_position=position,
        eta_s=eta,
        task=session.task,
        robot=session.robot,
        controller=session.controller,
        instruction=get_task(session.task).instruction,
        interfaces=session.interfaces,
        time_limit_s=session.time_limit_s,
        time_left_s=time_left,
        demos_done=session.demos_done,
        demos_required=session.demos_required,
        completion_code=session.completion_code,
        redirect_url=redirect,
        ice_servers=coordinator.ice_servers(session.id),
        ice_transport_policy=coordinator.config.ice_transport_policy,
        ended_reason=session.ended_reason,
        notice=_notice(session),
        ready_at=session.ready_at,
        preparing=preparation_view(coordinator.preparation.of(session)),
        accepted_required=progress.accepted_required if progress else None,
        accepted=progress.accepted if progress else None,
        awaiting_review=progress.awaiting_review if progress else None,
    )


def preparation_view(preparing: Preparing | None) -> RobotPreparation | None:
    if preparing is None:
        return None
    return RobotPreparation(eta_s=preparing.eta_s, total_s=preparing.total_s)


def _notice(session: Session) -> str | None:
    """What the page says while a session that had a robot waits for a new one."""
    requeued = session.queued_at is not None and session.queued_at > session.created_at
    if session.state not in ("queued", "starting") or not requeued or not session.error:
        return None
    why = session.error[:1].upper() + session.error[1:]
    done = session.demos_done
    plural = "s" if done != 1 else ""
    kept = f" Your {done} saved demonstration{plural} still count." if done else ""
    return f"{why}: a new robot is on its way.{kept}"
