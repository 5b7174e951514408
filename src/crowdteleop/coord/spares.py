"""Warm spare teleop servers: built before a worker arrives, handed over on admission.

A teleop server needs ~10 s to build its simulation; a spare that is already running takes
its session with one `POST /assign` (`crowdteleop.teleop.assign`), so a worker who clicks start
sees the robot in about a second. Spares are kept per (task, robot, controller); they count
against no session's slot, only against the machine's memory (~0.9 GiB each, ~2% of a core
while idle).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable

import aiohttp

from crowdteleop.coord.launcher import Launcher, LaunchError, TeleopHandle
from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.teleop.messages import Assignment

log = logging.getLogger(__name__)

SpareKey = tuple[str, str, str]  # task, robot, controller


class SparePool:
    def __init__(
        self,
        launcher: Launcher,
        make_config: Callable[[SpareKey], TeleopConfig],
        per_key: int,
    ) -> None:
        self.launcher = launcher
        self.make_config = make_config
        self.per_key = per_key
        self.ready: dict[SpareKey, list[tuple[TeleopHandle, TeleopConfig]]] = {}
        self._starting: dict[SpareKey, set[asyncio.Task[None]]] = {}
        self._closed = False

    def fill(self, keys: list[SpareKey]) -> None:
        """Start spares in the background until each key has `per_key` ready or starting."""
        if self._closed:
            return
        for key in keys:
            starting = self._starting.setdefault(key, set())
            for _ in range(self.per_key - len(self.ready.get(key, [])) - len(starting)):
                task = asyncio.create_task(self._start(key), name=f"spare-{key[0]}")
                starting.add(task)
                task.add_done_callback(starting.discard)

    async def _start(self, key: SpareKey) -> None:
        config = self.make_config(key)
        try:
            handle = await self.launcher.start(config)
        except (LaunchError, OSError) as exc:
            log.error("a spare teleop server for %s did not start: %s", key, exc)
            return
        if self._closed:
            await self.launcher.stop(handle)
            return
        self.ready.setdefault(key, []).append((handle, config))
        log.info("spare teleop server ready for %s at %s", key, handle.url)

    async def take(self, key: SpareKey, assignment: Assignment) -> TeleopHandle | None:
        """A running spare for `key`, now assigned to the session; None if there is none."""
        spares = self.ready.get(key, [])
        while spares:
            handle, config = spares.pop(0)
            if not self.launcher.alive(handle):
                continue
            try:
                await _assign(handle.url, config.admin_token or "", assignment)
            except (aiohttp.ClientError, TimeoutError, LaunchError) as exc:
                log.warning("spare at %s refused its session: %s", handle.url, exc)
                await self.launcher.stop(handle)
                continue
            return handle
        return None

    async def close(self) -> None:
        self._closed = True
        for tasks in self._starting.values():
            for task in list(tasks):
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await task
        for spares in self.ready.values():
            for handle, _config in spares:
                await self.launcher.stop(handle)
        self.ready.clear()


async def _assign(url: str, admin_token: str, assignment: Assignment) -> None:
    headers = {"Authorization": f"Bearer {admin_token}", "Content-Type": "application/json"}
    timeout = aiohttp.ClientTimeout(total=10)
    async with (
        aiohttp.ClientSession(timeout=timeout) as http,
        http.post(f"{url}/assign", data=assignment.model_dump_json(), headers=headers) as response,
    ):
        if response.status != 200:
            raise LaunchError(f"assign answered {response.status}: {await response.text()}")
