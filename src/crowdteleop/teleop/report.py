"""Tell the coordination server about each stored episode (it counts demonstrations)."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

import aiohttp

log = logging.getLogger(__name__)

ATTEMPTS = 5
FIRST_BACKOFF_S = 0.5


async def report_episode(url: str, token: str | None, payload: dict[str, Any]) -> bool:
    """POST `payload` to `url`, retrying with exponential backoff; False if it never landed.

    The report is idempotent on the coordinator's side (keyed by episode id), so a retry after
    a lost response never counts an episode twice.
    """
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    delay = FIRST_BACKOFF_S
    for attempt in range(1, ATTEMPTS + 1):
        try:
            async with (
                aiohttp.ClientSession(timeout=aiohttp.ClientTimeout(total=10)) as http,
                http.post(url, json=payload, headers=headers) as response,
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
