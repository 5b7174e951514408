"""Is each teleop server still working? A process that exists is not proof: one stopped
(SIGSTOP), deadlocked or swapped out holds its worker's slot while answering nothing. So the
coordinator asks each server's `/health` every `health_interval_s`, allowing
`health_timeout_s` for the answer; one with no good answer for `unresponsive_after_s` is
killed and its session queued again at its place (`Coordinator.restart`)."""

from __future__ import annotations

import asyncio
import logging
import time

import aiohttp

from crowdteleop.coord.fleet.launcher import TeleopHandle
from crowdteleop.coord.service.coordinator import Coordinator
from crowdteleop.teleop.messages import TeleopHealth

log = logging.getLogger(__name__)


async def _health(
    http: aiohttp.ClientSession, handle: TeleopHandle, timeout_s: float
) -> TeleopHealth | None:
    """The server's health, or None without a good answer in time."""
    try:
        timeout = aiohttp.ClientTimeout(total=timeout_s)
        async with http.get(f"{handle.url}/health", timeout=timeout) as response:
            if response.status != 200:
                return None
            return TeleopHealth.model_validate_json(await response.read())
    except (aiohttp.ClientError, TimeoutError, ValueError):  # ValidationError is a ValueError
        return None


async def probe_once(coordinator: Coordinator, http: aiohttp.ClientSession) -> list[str]:
    """Probe every running server at once; returns the sessions whose server was hung."""
    config = coordinator.config
    slots = [slot for slot in coordinator.pool.slots.values() if slot.handle is not None]
    answers = await asyncio.gather(
        *(_health(http, slot.handle, config.health_timeout_s) for slot in slots if slot.handle)
    )
    now = time.monotonic()
    hung = []
    for slot, health in zip(slots, answers, strict=True):
        if health is not None:
            slot.healthy_at = now
            slot.spool_pending = health.spool_pending
        elif now - slot.healthy_at > config.unresponsive_after_s:
            silent = now - slot.healthy_at
            why = f"the teleop server stopped responding ({silent:.0f} s without an answer)"
            if await coordinator.restart(slot.session_id, "hung", why):
                hung.append(slot.session_id)
            log.warning("session %s: %s", slot.session_id, why)
    return hung


async def run_liveness(coordinator: Coordinator) -> None:
    """Probe every `health_interval_s` until cancelled; one bad round never stops it."""
    async with aiohttp.ClientSession() as http:
        while True:
            await asyncio.sleep(coordinator.config.health_interval_s)
            try:
                await probe_once(coordinator, http)
            except asyncio.CancelledError:
                raise
            except Exception:
                log.exception("liveness probe failed")
