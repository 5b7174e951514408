"""Finished episodes, from the control loop to durable storage, the worker and the coordinator.

Storing runs in tasks of its own, off the loop: the worker hears `saved` only once the store
confirmed the file, then the coordinator gets an `EpisodeReport` (it counts demonstrations)
through the report outbox, which keeps it until the coordinator confirms it.
"""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from crowdteleop.recording.storage import disk_is_full
from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.teleop.episode import FinishedEpisode
from crowdteleop.teleop.messages import EpisodeAck, EpisodeReport
from crowdteleop.teleop.peering import PeerSet
from crowdteleop.teleop.protocol import EpisodeEnded, EpisodeSaved, ErrorEvent
from crowdteleop.teleop.report import PendingReport, ReportOutbox
from crowdteleop.teleop.session import TeleopSession
from crowdteleop.teleop.telemetry import SessionTelemetry

log = logging.getLogger(__name__)


class EpisodeArchive:
    """Owns the storing tasks; `close` waits for them."""

    def __init__(self, peers: PeerSet, telemetry: SessionTelemetry) -> None:
        self._peers = peers
        self._telemetry = telemetry
        self._tasks: set[asyncio.Task[None]] = set()
        self.stored: list[str] = []
        self.reports = ReportOutbox(
            on_unreachable=self._reports_unreachable, on_ack=self._acknowledged
        )

    def _acknowledged(self, ack: EpisodeAck) -> None:
        """The coordinator counted an episode: the worker hears how it compares, if it said."""
        if ack.feedback is not None:
            self._peers.broadcast(ack.feedback)

    def _reports_unreachable(self, url: str) -> None:
        self._telemetry.errors["report_unreachable"] += 1
        self._peers.broadcast(reports_delayed())

    def episode_ended(
        self,
        session: TeleopSession,
        finished: FinishedEpisode,
        config: TeleopConfig,
        telemetry: dict[str, Any],
    ) -> None:
        """Tell the peers at once; store and report in the background."""
        self._peers.broadcast(
            EpisodeEnded(
                episode=finished.number,
                outcome=finished.outcome,
                steps=finished.steps,
                successes=session.tracker.successes,
            )
        )
        task = asyncio.create_task(self._store(session, finished, config, telemetry))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _store(
        self,
        session: TeleopSession,
        finished: FinishedEpisode,
        config: TeleopConfig,
        telemetry: dict[str, Any],
    ) -> None:
        try:
            stored = await session.store(finished, {"telemetry": telemetry})
        except Exception as error:
            log.exception("storing episode %s failed", finished.episode_id)
            self._telemetry.errors["storage"] += 1
            full = disk_is_full(error)
            why = "the server's disk is full" if full else "the server could not store it"
            self._peers.broadcast(
                ErrorEvent(
                    code="not_saved",
                    message=f"Episode {finished.number} could not be saved ({why}), so it "
                    "does not count. Please tell the study team.",
                )
            )
            return
        if stored is None:
            return
        uri = stored.uri
        self.stored.append(uri)
        self._peers.broadcast(
            EpisodeSaved(episode=finished.number, outcome=finished.outcome, uri=uri)
        )
        if config.report_url is None:
            return
        report = EpisodeReport(
            session_id=config.session_id,
            worker_id=config.worker_id,
            episode=finished.number,
            episode_id=finished.episode_id,
            outcome=finished.outcome,
            steps=finished.steps,
            duration_s=finished.steps / config.sim.control_hz,
            uri=uri,
            telemetry=telemetry,
            device=finished.device,
            metrics=stored.metrics,
        )
        self.reports.put(PendingReport(config.report_url, config.report_token, report))

    async def close(self) -> None:
        if self._tasks:
            await asyncio.gather(*self._tasks, return_exceptions=True)
        await self.reports.close()


def reports_delayed() -> ErrorEvent:
    """What a worker reads while the coordinator does not hear of their demonstrations."""
    return ErrorEvent(
        code="reports_delayed",
        message="Your demonstrations are saved, but the study server cannot be reached to "
        "count them. They are kept and will count as soon as it answers: you can go on.",
    )
