"""Is each teleop server still working? A process that exists is not proof: one stopped
(SIGSTOP), deadlocked or swapped out holds its worker's slot while answering nothing. So the
coordinator asks each server's `/health` every `health_interval_s`, allowing
`health_timeout_s` for the answer; one with no good answer for `unresponsive_after_s` is
killed and its session queued again at its place (`Coordinator.restart`)."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Awaitable, Callable

import aiohttp

from crowdteleop.coord.fleet.pool import TeleopPool
from crowdteleop.coord.fleet.teleop_http import health
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.metrics import RestartCause

Restart = Callable[[str, RestartCause, str], Awaitable[bool]]
log = logging.getLogger(__name__)


class Liveness:
    """Probes the servers of `pool`'s slots; `restart` is the Coordinator's."""

    def __init__(self, pool: TeleopPool, config: CoordConfig, restart: Restart) -> None:
        self.pool, self.config, self.restart = pool, config, restart

    async def probe_once(self, http: aiohttp.ClientSession) -> list[str]:
        """Probe every running server at once; returns the sessions whose server was hung."""
        config = self.config
        running = self.pool.running()
        answers = await asyncio.gather(
            *(health(http, handle.url, config.health_timeout_s) for _, handle in running)
        )
        now = time.monotonic()
        hung = []
        for (session_id, _handle), answer in zip(running, answers, strict=True):
            silent = self.pool.heard(session_id, answer, now)
            if silent > config.unresponsive_after_s:
                why = f"the teleop server stopped responding ({silent:.0f} s without an answer)"
                if await self.restart(session_id, "hung", why):
                    hung.append(session_id)
                log.warning("session %s: %s", session_id, why)
        return hung
