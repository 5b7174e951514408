"""Demonstrations left in the spool of a session that has ended are uploaded by the
coordinator.

A teleop server whose object store is down keeps finished episodes in a spool on disk and
uploads them when the store returns. If the session ends first (the worker is done, or left),
its server stops and nothing would ever start for that spool again: an outage longer than a
session would strand its demonstrations. So the coordinator sweeps the spools of ended
sessions and drains them, as the server would have.
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

from crowdteleop.coord.db.sessions import SessionStore
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.recording.s3 import S3Config, S3Storage
from crowdteleop.recording.spool import SpooledStorage
from crowdteleop.teleop.config import TeleopConfig

log = logging.getLogger(__name__)
SWEEP_INTERVAL_S = 10.0
DRAIN_TIMEOUT_S = 30.0


def _drain(s3: S3Config, spool: Path) -> int:
    """Upload what `spool` holds; how many objects the store confirmed."""
    storage = SpooledStorage(S3Storage(s3), spool, start=False)
    try:
        before = storage.pending_count()
        storage.start()
        storage.drain(DRAIN_TIMEOUT_S)
        return before - storage.pending_count()
    finally:
        storage.close()


class SpoolSweeper:
    """Drains the spools of ended sessions (the Coordinator runs it every `SWEEP_INTERVAL_S`)."""

    def __init__(self, config: CoordConfig, sessions: SessionStore) -> None:
        self.config, self.sessions = config, sessions

    async def sweep_once(self) -> int:
        """Drain the spools of ended sessions once; the number of episodes uploaded."""
        storage = TeleopConfig.model_validate(self.config.teleop).recording.storage
        if storage.kind != "s3" or storage.s3 is None or storage.spool_directory is not None:
            return 0  # nothing spooled, or one shared spool that live servers drain themselves
        uploaded = 0
        for spool in sorted((self.config.data_dir / "episodes").glob("*/*/spool")):
            if not any(spool.glob("*.json")):
                continue
            session = await self.sessions.session(spool.parent.name)
            if session is None or session.state != "ended":
                continue  # a live (or relaunching) server owns this spool
            count = await asyncio.to_thread(_drain, storage.s3, spool)
            if count:
                log.info("uploaded %d episode(s) left in the spool of %s", count, session.id)
            uploaded += count
        return uploaded
