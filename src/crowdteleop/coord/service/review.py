"""Reviewing demonstrations (docs/review.md): a reviewer's accept, reject and undo, the
campaign's automatic decisions by score, and each decision stored beside its episode file.

The database keeps the history (`coord.db.reviews`); after each decision the service writes
it as a `recording.review.ReviewRecord` next to the episode (`<name>.review.<seq>.json`, never
overwritten), so `crowdteleop dataset build --filter accepted` needs no database, then calls
the `on_decided` hook it was given (the completion hold's, coord/service/completion.py). A
sidecar that cannot be written is logged: the decision stands, the database has it.
"""

from __future__ import annotations

import asyncio
import logging
import os
import posixpath
import tempfile
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import unquote, urlparse

from crowdteleop.coord.db.reviews import (
    EpisodeNotFoundError,
    NothingToUndoError,
    ReviewConflictError,
    ReviewPage,
)
from crowdteleop.coord.db.reviews import ReviewFilters as ReviewFilters
from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Episode, ReviewDecisionRow
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.metrics import CoordMetrics
from crowdteleop.recording.review import ReviewRecord, review_name
from crowdteleop.recording.s3 import S3Config, S3Storage
from crowdteleop.recording.storage import fsync_directory
from crowdteleop.recording.stores import StorageConfig
from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.vocab import ReviewDecision

log = logging.getLogger(__name__)
AUTO = "auto"  # the reviewer of the campaign's automatic decisions
OnDecided = Callable[[Episode], Awaitable[None]]


class DecidedMeanwhileError(ApiError):
    """409: the episode was decided since the reviewer looked; where it stands now."""

    def __init__(self, episode: Episode, last: ReviewDecisionRow | None) -> None:
        who = f"{last.reviewer} ({last.decision or 'undone'})" if last else "someone"
        super().__init__(
            409,
            "conflict",
            f"decided by {who} meanwhile: episode {episode.episode_id} is now "
            f"{episode.decision or 'undecided'} at decision {episode.review_seq}; look again",
        )
        self.episode, self.last = episode, last


@dataclass(frozen=True)
class Decided:
    episode: Episode
    decision: ReviewDecisionRow


def storage_config(config: CoordConfig) -> StorageConfig:
    """Where the teleop servers store episodes: the coordinator's `teleop.recording.storage`."""
    return TeleopConfig.model_validate(config.teleop).recording.storage


def local_path(uri: str) -> Path | None:
    """The local file a file:// URI names; None for another scheme."""
    parsed = urlparse(uri)
    return Path(unquote(parsed.path)) if parsed.scheme == "file" else None


def s3_key(uri: str, s3: S3Config) -> str:
    """The storage key (below the configured prefix) of an s3:// episode URI."""
    prefix = s3.prefix if not s3.prefix or s3.prefix.endswith("/") else s3.prefix + "/"
    head = f"s3://{s3.bucket}/{prefix}"
    if not uri.startswith(head):
        raise ValueError(f"{uri} is not in the configured store {head}")
    return uri[len(head) :]


class Sidecars:
    """Writes each decision beside its episode file, locally or in the object store."""

    def __init__(self, storage: StorageConfig) -> None:
        self._storage = storage
        self._s3: S3Storage | None = None

    def write(self, uri: str, record: ReviewRecord) -> None:
        """Blocking: call in a thread."""
        text = record.model_dump_json(indent=1)
        path = local_path(uri)
        if path is not None:
            write_once(path.parent / review_name(path.name, record.seq), text)
            return
        if not uri.startswith("s3://") or self._storage.s3 is None:
            raise ValueError(f"cannot store a decision beside {uri}: not file:// or the S3 store")
        key = s3_key(uri, self._storage.s3)
        name = review_name(posixpath.basename(key), record.seq)
        with tempfile.TemporaryDirectory(prefix="review-") as scratch:
            local = Path(scratch) / name
            local.write_text(text, encoding="utf-8")
            self._s3 = self._s3 or S3Storage(self._storage.s3)
            self._s3.put(local, posixpath.join(posixpath.dirname(key), name))


def write_once(target: Path, text: str) -> None:
    """`text` at `target` atomically, never over an existing file (a decision is immutable:
    the same one written twice is harmless)."""
    handle, temporary = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as file:
            file.write(text)
            file.flush()
            os.fsync(file.fileno())
        os.link(temporary, target)
    except FileExistsError:
        pass
    finally:
        os.unlink(temporary)
    fsync_directory(target.parent)


class Reviews:
    """Decisions on episodes: the API's, and the campaign's automatic ones."""

    def __init__(
        self,
        store: Store,
        config: CoordConfig,
        metrics: CoordMetrics,
        on_decided: OnDecided | None = None,
    ) -> None:
        self._reviews, self._config, self._metrics = store.reviews, config, metrics
        self._on_decided = on_decided
        self._sidecars = Sidecars(storage_config(config))

    async def page(self, filters: ReviewFilters) -> ReviewPage:
        return await self._reviews.page(filters)

    async def episode(self, episode_id: str) -> tuple[Episode, list[ReviewDecisionRow]]:
        """The episode and its decisions, first first; 404 if there is none."""
        episode = await self._reviews.episode(episode_id)
        if episode is None:
            raise self._unknown(episode_id)
        return episode, await self._reviews.history(episode_id)

    async def decide(
        self,
        episode_id: str,
        expected_seq: int,
        decision: ReviewDecision,
        reason: str,
        reviewer: str,
    ) -> Decided:
        """A reviewer's accept or reject, against the decision count they saw."""
        try:
            row = await self._reviews.decide(episode_id, expected_seq, decision, reason, reviewer)
        except (EpisodeNotFoundError, ReviewConflictError) as error:
            raise self._refusal(error) from None
        return await self._after(row)

    async def undo(self, episode_id: str, expected_seq: int, reviewer: str) -> Decided:
        """Undo the episode's last decision, itself a decision in its history (coord.db.reviews)."""
        try:
            row = await self._reviews.undo(episode_id, expected_seq, reviewer)
        except NothingToUndoError:
            self._metrics.refused("review_conflict")
            raise ApiError(
                409, "nothing_to_undo", f"{episode_id} has no decision to undo"
            ) from None
        except (EpisodeNotFoundError, ReviewConflictError) as error:
            raise self._refusal(error) from None
        return await self._after(row)

    async def automatic(self, episode_id: str, campaign: str | None) -> Decided | None:
        """The campaign's score rule on a freshly judged episode: accepted if successful,
        unflagged and scoring at least `auto_accept_score`, rejected if scoring below
        `auto_reject_score` (reviewer "auto"); None when neither applies."""
        settings = self._config.campaign(campaign)
        episode = await self._reviews.episode(episode_id)
        if settings is None or episode is None or episode.score is None:
            return None
        policy, score = settings.review, episode.score
        decision: ReviewDecision | None = None
        if policy.auto_reject_score is not None and score < policy.auto_reject_score:
            decision = "rejected"
        elif policy.auto_accept_score is not None and score >= policy.auto_accept_score:
            clean = episode.outcome == "success" and not episode.flags
            decision = "accepted" if clean else None
        if decision is None or episode.review_seq != 0:
            return None
        reason = f"score {score:.0f} {'below' if decision == 'rejected' else 'at least'} the rule"
        try:
            row = await self._reviews.decide(episode_id, 0, decision, reason, AUTO, automatic=True)
        except ReviewConflictError:
            return None  # a reviewer was quicker
        return await self._after(row, hook=False)

    async def _after(self, row: ReviewDecisionRow, hook: bool = True) -> Decided:
        """The sidecar beside the episode file, then the hook."""
        episode = await self._reviews.episode(row.episode_id)
        assert episode is not None  # decisions cascade with their episode
        record = ReviewRecord.model_validate(row, from_attributes=True)
        try:
            await asyncio.to_thread(self._sidecars.write, episode.uri, record)
        except Exception:
            log.exception("decision %d on %s not stored beside its file", row.seq, episode.uri)
        if hook and self._on_decided is not None:
            try:
                await self._on_decided(episode)
            except Exception:
                log.exception("the on_decided hook failed for %s", episode.episode_id)
        return Decided(episode, row)

    def _refusal(self, error: Exception) -> ApiError:
        if isinstance(error, ReviewConflictError):
            self._metrics.refused("review_conflict")
            return DecidedMeanwhileError(error.episode, error.last)
        assert isinstance(error, EpisodeNotFoundError)
        return self._unknown(error.episode_id)

    def _unknown(self, episode_id: str) -> ApiError:
        self._metrics.refused("review_unknown_episode")
        return ApiError(404, "not_found", f"no episode {episode_id!r}")
