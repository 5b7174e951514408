"""Episode reports from teleop servers: each recorded once; the last required success
completes the session with its completion code. And the recorded episodes, for the admin."""

from __future__ import annotations

import time
from dataclasses import dataclass

from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Episode, Session
from crowdteleop.coord.service.completion import Completion
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.feedback import worker_feedback
from crowdteleop.coord.service.metrics import CoordMetrics
from crowdteleop.coord.service.review import Reviews
from crowdteleop.recording.quality import (
    SCORED_METRICS,
    EpisodeMetrics,
    QualityThresholds,
    quality_flags,
    quality_score,
)
from crowdteleop.teleop.messages import EpisodeReport
from crowdteleop.teleop.protocol import EpisodeFeedback


@dataclass(frozen=True)
class Recorded:
    """What recording a report did."""

    new: bool  # False: a retried report, counted before
    demos_done: int
    completed: bool  # this report completed the session
    feedback: EpisodeFeedback | None = None  # for a measured successful demonstration


class Episodes:
    def __init__(
        self,
        store: Store,
        config: CoordConfig,
        metrics: CoordMetrics,
        completion: Completion,
        reviews: Reviews,
    ) -> None:
        """`completion` and `reviews` are the app's: a report's automatic decision and its
        completion check go through the same services a reviewer's decision does."""
        self._episodes, self._sessions = store.episodes, store.sessions
        self._config, self._metrics = config, metrics
        self._completion, self._reviews = completion, reviews

    async def reporting_session(self, report_token: str) -> Session | None:
        """The session whose teleop server holds `report_token`."""
        return await self._sessions.session_by_report_token(report_token)

    async def record(self, session: Session, report: EpisodeReport) -> Recorded:
        """Record the episode (once); the last required success completes the session."""
        interface = report.device if report.device not in (None, "bot") else session.interface
        new, done = await self._episodes.add_episode(
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
                metrics=report.metrics.model_dump(mode="json", exclude_none=True)
                if report.metrics is not None
                else None,
            )
        )
        feedback = None
        if new:
            self._metrics.episodes.labels(outcome=report.outcome).inc()
            if report.metrics is not None:
                feedback = await self._judge(session, report, report.metrics)
                await self._reviews.automatic(report.episode_id, session.campaign)
        completed = False
        if new and report.outcome == "success":  # the code may wait for reviews: completion.py
            completed = await self._completion.after_success(session, done)
        return Recorded(new, done, completed, feedback)

    async def _judge(
        self, session: Session, report: EpisodeReport, metrics: EpisodeMetrics
    ) -> EpisodeFeedback | None:
        """Its score against the campaign's successful episodes of its task so far (itself
        included) and the flags its campaign's thresholds raise, kept with it; for a
        successful one, the worker's feedback (docs/quality.md)."""
        campaign = self._config.campaign(session.campaign)
        thresholds = campaign.quality if campaign is not None else QualityThresholds()
        distributions = {
            name: await self._episodes.metric_values(name, session.task, session.campaign)
            for name in SCORED_METRICS
        }
        flags = quality_flags(metrics, thresholds)
        score = quality_score(metrics, distributions)
        await self._episodes.judge(report.episode_id, score, [flag.model_dump() for flag in flags])
        if report.outcome != "success":
            return None
        return worker_feedback(report.episode, metrics, distributions, score, flags)

    async def of_session(self, session_id: str) -> list[Episode]:
        """A session's episodes, oldest first."""
        return await self._episodes.episodes(session_id)

    async def all(self) -> list[Episode]:
        return await self._episodes.episodes()

    async def metric_values(self, name: str, task: str | None = None) -> list[float]:
        """A metric's values over the recorded episodes (of `task`), ascending."""
        return await self._episodes.metric_values(name, task)

    async def since(self, since: float) -> list[Episode]:
        return await self._episodes.episodes_since(since)

    async def totals(self) -> dict[str, int]:
        """Workers, sessions, completed sessions, episodes and successes so far."""
        return await self._episodes.totals()
