"""Episode reports from teleop servers: each recorded once; the last required success
completes the session with its completion code."""

from __future__ import annotations

import time

from crowdteleop.coord.api.schemas import EpisodeAck
from crowdteleop.coord.db.tables import Episode, Session
from crowdteleop.coord.guard.security import new_completion_code
from crowdteleop.coord.service.coordinator import Coordinator
from crowdteleop.teleop.messages import EpisodeReport


async def report_episode(
    coordinator: Coordinator, session: Session, report: EpisodeReport
) -> EpisodeAck:
    """Record the episode (once); the last required success completes the session."""
    interface = report.device if report.device not in (None, "bot") else session.interface
    new, done = await coordinator.store.add_episode(
        Episode(
            episode_id=report.episode_id,
            session_id=session.id,
            worker_id=session.worker_id,
            number=report.episode,
            outcome=report.outcome,
            steps=report.steps,
            duration_s=report.duration_s,
            uri=report.uri,
            interface=interface,
            task=session.task,
            telemetry=report.telemetry,
            created_at=time.time(),
        )
    )
    if new:
        coordinator.metrics.episodes.labels(outcome=report.outcome).inc()
    completed = False
    if new and report.outcome == "success" and done >= session.demos_required:
        campaign = coordinator.config.campaign(session.campaign)
        code = (campaign.prolific_completion_code if campaign else None) or (new_completion_code())
        # A short grace lets the page hear about the saved episode before the server goes.
        completed = await coordinator.end(
            session.id, "completed", completion_code=code, stop_delay_s=2.0
        )
    return EpisodeAck(
        episode_id=report.episode_id,
        duplicate=not new,
        demos_done=done,
        demos_required=session.demos_required,
        completed=completed,
    )
