"""Tell the coordination server about each stored episode (it counts demonstrations).

Reports wait in an outbox until the coordinator confirms each one: a coordinator that is
restarting, or out of reach for minutes, costs the worker no demonstration. Each report is
idempotent on the coordinator's side (keyed by episode id), so a retry after a lost answer
never counts an episode twice. While the coordinator cannot be reached, the server says so:
in its log, to the worker's page (through `on_unreachable`) and in `/health`
(`reports_pending`, summed into the coordinator's `/metrics` by its probes). Each answer
(`EpisodeAck`) goes to `on_ack`: the worker's feedback rides on it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import aiohttp
from pydantic import ValidationError

from crowdteleop.teleop.messages import EpisodeAck, EpisodeReport

log = logging.getLogger(__name__)

FIRST_BACKOFF_S = 0.5
MAX_BACKOFF_S = 5.0  # a coordinator back from a restart hears of every episode within this
REQUEST_TIMEOUT_S = 10.0
CLOSE_GRACE_S = 10.0  # a stopping server waits this long for its last reports to land

Delivery = Literal["delivered", "refused", "unreachable"]


@dataclass(frozen=True)
class PendingReport:
    """One report and where it goes (a warm spare learns both only when it is assigned)."""

    url: str
    token: str | None
    report: EpisodeReport


async def post_report(
    http: aiohttp.ClientSession, pending: PendingReport
) -> tuple[Delivery, EpisodeAck | None]:
    """One attempt: delivered (2xx, with the coordinator's answer when it reads as an
    `EpisodeAck`), refused (3xx, 4xx: retrying will not help) or unreachable (no answer, or
    the coordinator's own trouble, 5xx)."""
    headers = {"Content-Type": "application/json"}
    if pending.token:
        headers["Authorization"] = f"Bearer {pending.token}"
    body = pending.report.model_dump_json()
    try:
        async with http.post(pending.url, data=body, headers=headers) as response:
            text = await response.text()
            if response.status < 300:
                return "delivered", _ack(text)
            if response.status < 500:
                log.error("episode report refused (%s): %s", response.status, text[:500])
                return "refused", None
            log.warning("episode report answered %s: %s", response.status, text[:200])
    except (aiohttp.ClientError, TimeoutError) as exc:
        log.warning("episode report to %s failed: %s", pending.url, exc)
    return "unreachable", None


def _ack(text: str) -> EpisodeAck | None:
    """The coordinator's answer; None from one that answers otherwise (it still counted)."""
    try:
        return EpisodeAck.model_validate_json(text)
    except ValidationError as error:
        log.warning("the coordinator's answer to a report is not an EpisodeAck: %s", error)
        return None


class ReportOutbox:
    """Reports in the order their episodes were stored, each kept until delivered or refused.

    `on_unreachable(url)` is called once per stretch of failures (and by `probe` at start, when
    the report address does not answer), so the worker hears it once, not per attempt.
    """

    def __init__(
        self,
        on_unreachable: Callable[[str], None],
        on_ack: Callable[[EpisodeAck], None] | None = None,
    ) -> None:
        self._on_unreachable = on_unreachable
        self._on_ack = on_ack
        self._queue: deque[PendingReport] = deque()
        self._wake = asyncio.Event()
        self._task: asyncio.Task[None] | None = None
        self.unreachable: str | None = None  # the address that did not answer, while so
        self.delivered = 0
        self.refused = 0
        self.failed_attempts = 0

    @property
    def pending(self) -> int:
        return len(self._queue)

    def put(self, pending: PendingReport) -> None:
        self._queue.append(pending)
        self._wake.set()
        if self._task is None or self._task.done():
            self._task = asyncio.create_task(self._deliver_forever(), name="episode-reports")

    async def probe(self, url: str) -> bool:
        """Whether the report address answers at all (any HTTP status will do: a GET on a
        POST route says 405). A server that cannot reach it says so before any episode."""
        timeout = aiohttp.ClientTimeout(total=REQUEST_TIMEOUT_S)
        try:
            async with aiohttp.ClientSession(timeout=timeout) as http, http.get(url):
                return True
        except (aiohttp.ClientError, TimeoutError) as exc:
            log.error(
                "cannot reach the coordinator at %s to report episodes (%s): demonstrations "
                "are stored but not counted until it answers; check the coordinator's "
                "internal_url (docs/deploy.md)",
                url,
                exc,
            )
            self._mark_unreachable(url)
            return False

    async def _deliver_forever(self) -> None:
        timeout = aiohttp.ClientTimeout(total=REQUEST_TIMEOUT_S)
        async with aiohttp.ClientSession(timeout=timeout) as http:
            delay = FIRST_BACKOFF_S
            while self._queue:
                head = self._queue[0]
                outcome, ack = await post_report(http, head)
                if outcome == "unreachable":
                    self.failed_attempts += 1
                    self._mark_unreachable(head.url)
                    self._wake.clear()
                    with contextlib.suppress(TimeoutError):  # a new report: try again now
                        await asyncio.wait_for(self._wake.wait(), delay)
                    delay = min(delay * 2, MAX_BACKOFF_S)
                    continue
                self._queue.popleft()
                delay = FIRST_BACKOFF_S
                if outcome == "refused":
                    self.refused += 1
                    continue
                self.delivered += 1
                if ack is not None and self._on_ack is not None:
                    self._on_ack(ack)
                if self.unreachable is not None:
                    log.info("the coordinator answers again: reports delivered")
                    self.unreachable = None

    def _mark_unreachable(self, url: str) -> None:
        if self.unreachable is None:
            self.unreachable = url
            self._on_unreachable(url)

    async def close(self, grace_s: float = CLOSE_GRACE_S) -> None:
        """Give the last reports `grace_s` to land; name each one that did not."""
        if self._task is not None and not self._task.done():
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.shield(self._task), grace_s)
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
        for pending in self._queue:
            log.error(
                "episode %s (%s) was stored at %s but never reported: the coordinator did not "
                "answer",
                pending.report.episode_id,
                pending.report.outcome,
                pending.report.uri,
            )
