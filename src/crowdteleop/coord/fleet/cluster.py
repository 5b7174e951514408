"""A cluster launcher's room is the cluster's, and changes as nodes come and go: read again at
each reaper sweep, less every replica's warm spares (which hold slots there too); and the
cluster is told how many sessions want a slot, for its autoscaler.

The spares' slots are kept for them even while one is missing (handed to a worker, its
replacement not yet listed): a session admitted into that gap would take the slot its
replacement needs, and the cluster would hold one session more than it should."""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable, Callable

from crowdteleop.coord.db.spare_registry import SpareKey, SpareRegistry
from crowdteleop.coord.fleet.launcher import ClusterLauncher, Launcher


class ClusterRoom:
    def __init__(
        self,
        launcher: Launcher,
        spares: SpareRegistry,
        spares_wanted: Callable[[], Awaitable[dict[SpareKey, int]]],
    ) -> None:
        """`spares_wanted()`: how many spares each kind should have (`spare_servers`)."""
        self.launcher, self.spares, self.spares_wanted = launcher, spares, spares_wanted

    async def sessions(self) -> int | None:
        """How many sessions the cluster holds now; None for a launcher of fixed size."""
        if not isinstance(self.launcher, ClusterLauncher):
            return None
        slots = await asyncio.to_thread(self.launcher.capacity)
        wanted = sum((await self.spares_wanted()).values())
        return max(0, slots - max(wanted, await self.spares.count()))  # every replica's

    async def request(self, sessions: int) -> None:
        """Ask for room for `sessions` at once (a no-op off a cluster, or without autoscaler)."""
        if isinstance(self.launcher, ClusterLauncher):
            await asyncio.to_thread(self.launcher.request, sessions)
