"""A cluster launcher's capacity is the cluster's, and changes as nodes come and go: each
reaper sweep reads it (less every replica's warm spares, which hold slots there too), admits queued
sessions into new room, and tells the cluster how many sessions want a slot."""

from __future__ import annotations

import asyncio
import logging

from crowdteleop.coord.fleet.launcher import ClusterLauncher
from crowdteleop.coord.service.coordinator import Coordinator

log = logging.getLogger(__name__)


async def follow_cluster(coordinator: Coordinator, admit: bool = True) -> None:
    launcher = coordinator.pool.launcher
    if not isinstance(launcher, ClusterLauncher):
        return
    slots = await asyncio.to_thread(launcher.capacity)
    capacity = max(0, slots - await coordinator.spares.registry.count())  # every replica's
    if capacity != coordinator.pool.capacity:
        log.info("cluster capacity %d -> %d sessions", coordinator.pool.capacity, capacity)
        coordinator.pool.capacity = capacity
        coordinator.metrics.capacity.set(capacity)
        if admit:
            await coordinator.admit()
    live = await coordinator.store.live_sessions()
    await asyncio.to_thread(launcher.request, len(live) + coordinator.config.spare_servers)
