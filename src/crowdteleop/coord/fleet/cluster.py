"""A cluster launcher's room is the cluster's, and changes as nodes come and go: read again at
each reaper sweep, less every replica's warm spares (which hold slots there too); and the
cluster is told how many sessions want a slot, for its autoscaler."""

from __future__ import annotations

import asyncio

from crowdteleop.coord.db.spare_registry import SpareRegistry
from crowdteleop.coord.fleet.launcher import ClusterLauncher, Launcher


class ClusterRoom:
    def __init__(self, launcher: Launcher, spares: SpareRegistry) -> None:
        self.launcher, self.spares = launcher, spares

    async def sessions(self) -> int | None:
        """How many sessions the cluster holds now; None for a launcher of fixed size."""
        if not isinstance(self.launcher, ClusterLauncher):
            return None
        slots = await asyncio.to_thread(self.launcher.capacity)
        return max(0, slots - await self.spares.count())  # every replica's

    async def request(self, sessions: int) -> None:
        """Ask for room for `sessions` at once (a no-op off a cluster, or without autoscaler)."""
        if isinstance(self.launcher, ClusterLauncher):
            await asyncio.to_thread(self.launcher.request, sessions)
