"""Tell the coordination server about each stored episode (it counts demonstrations)."""

from __future__ import annotations

import asyncio
import logging

import aiohttp

from crowdteleop.teleop.messages import EpisodeReport

log = logging.getLogger(__name__)

ATTEMPTS = 5
FIRST_BACKOFF_S = 0.5


async def report_episode(url: str, token: str | None, report: EpisodeReport) -> bool:
    """POST `report` to `url`, retrying with exponential backoff; False if it never landed.

    The report is idempotent on the coordinator's side (keyed by episode id), so a retry after
    a lost response never counts an episode twice.
    """
    headers = {"Content-Type": "application/json"}
    if token:
        headers["Authorization"] = f"Bearer {token}"
    body = report.model_dump_json()
    delay = FIRST_BACKOFF_S
    for attempt in range(1, ATTEMPTS + 1):
        try:
            async with (
                aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=10)) as http,
                http.post(url, data=body, headers=headers) as response,
            ):
                if response.status < 300:
                    return True
                if 400 <= response.status < 500:  # our fault: retrying will not help
                    log.error(
                        "episode report refused (%s): %s", response.status, await response.text()
                    )
                    return False
        except (aiohttp.ClientError, TimeoutError) as exc:
            log.warning("episode report attempt %d failed: %s", attempt, exc)
        await asyncio.sleep(delay)
        delay *= 2
    return False
