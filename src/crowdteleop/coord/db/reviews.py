"""Review decisions in the database: each accept, reject or undo one `review_decisions` row,
never changed, and the episode's current decision beside it; and the episodes grid the
reviewer page pages through (docs/review.md).

Two reviewers deciding on one episode at once are told apart by optimistic concurrency: each
decides against the decision count it saw (`expected_seq`); the store moves the episode from
that count to the next in one conditional UPDATE, so of two deciding on the same count exactly
one lands, and the other gets a `ReviewConflictError` carrying the decision that won. The
UNIQUE(episode_id, seq) constraint is the backstop.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Literal, Self

from pydantic import BaseModel, ConfigDict, Field, model_validator
from sqlalchemy import ColumnElement, String, cast, func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.ext.asyncio import AsyncSession, async_sessionmaker

from crowdteleop.coord.db.engine import rowcount
from crowdteleop.coord.db.tables import Episode, ReviewDecisionRow
from crowdteleop.vocab import REVIEW_DECISIONS, Outcome, ReviewDecision

NAME = r"^[A-Za-z0-9_.:-]{1,64}$"
UNFLAGGED = ("null", "[]")  # the JSON text of an episode's flags when there are none


class ReviewFilters(BaseModel):
    """Which episodes the reviewer's grid shows, in what order (the query of
    `GET /api/review/episodes`; a malformed one is a 422 naming the field)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    task: str | None = Field(None, pattern=NAME, description="only this task's episodes")
    worker: str | None = Field(None, pattern=NAME, description="only this worker's")
    decision: ReviewDecision | Literal["undecided"] | None = Field(
        None, description="accepted, rejected, or undecided (never decided, or undone)"
    )
    flagged: bool | None = Field(None, description="only flagged (true) or unflagged (false)")
    score_min: float | None = Field(None, ge=0, le=100)
    score_max: float | None = Field(None, ge=0, le=100)
    outcome: Outcome | None = None
    sort: Literal["score", "created_at", "duration_s"] = "created_at"
    descending: bool = True
    limit: int = Field(48, ge=1, le=200)
    offset: int = Field(0, ge=0, le=1_000_000)

    @model_validator(mode="after")
    def _min_below_max(self) -> Self:
        low, high = self.score_min, self.score_max
        if low is not None and high is not None and low > high:
            raise ValueError(f"score_min ({low}) is above score_max ({high})")
        return self


@dataclass(frozen=True)
class ReviewPage:
    episodes: list[Episode]
    total: int  # how many pass the filters


class EpisodeNotFoundError(Exception):
    """No episode has this id."""

    def __init__(self, episode_id: str) -> None:
        super().__init__(f"no episode {episode_id!r}")
        self.episode_id = episode_id


class ReviewConflictError(Exception):
    """The episode was decided since the reviewer looked: `current` is where it stands now
    (its decision, count, and the row that made it, None if it has none)."""

    def __init__(self, episode: Episode, last: ReviewDecisionRow | None) -> None:
        super().__init__(f"episode {episode.episode_id} is at decision {episode.review_seq}")
        self.episode, self.last = episode, last


class NothingToUndoError(Exception):
    """The episode has no decision to undo."""


class ReviewStore:
    """The decisions (history and current) and the reviewer's grid."""

    def __init__(self, transactions: async_sessionmaker[AsyncSession]) -> None:
        self.transactions = transactions

    async def decide(
        self,
        episode_id: str,
        expected_seq: int,
        decision: ReviewDecision | None,
        reason: str,
        reviewer: str,
        automatic: bool = False,
    ) -> ReviewDecisionRow:
        """Record a decision (None: undecided) on the episode, if it still has
        `expected_seq` decisions; its history row, in one transaction with the episode's
        current decision. Raises `EpisodeNotFoundError` or `ReviewConflictError`."""
        row = ReviewDecisionRow(
            episode_id=episode_id,
            seq=expected_seq + 1,
            decision=decision,
            reason=reason,
            reviewer=reviewer,
            automatic=automatic,
            at=time.time(),
        )
        try:
            async with self.transactions.begin() as db:
                result = await db.execute(
                    update(Episode)
                    .where(Episode.episode_id == episode_id, Episode.review_seq == expected_seq)
                    .values(decision=decision, review_seq=expected_seq + 1)
                )
                if rowcount(result) == 0:
                    raise _LostRaceError
                db.add(row)
        except (_LostRaceError, IntegrityError):
            raise await self._refusal(episode_id) from None
        return row

    async def undo(
        self, episode_id: str, expected_seq: int, reviewer: str, reason: str = "undo"
    ) -> ReviewDecisionRow:
        """Undo the last decision. An undo is itself a decision, kept in the history like any
        other: a new row whose decision is the one the episode had before the last (None if
        the last was its first), so nothing is ever erased, and undoing an undo redoes.
        Raises `NothingToUndoError` on an episode never decided, and what `decide` raises."""
        history = await self.history(episode_id)
        if not history:
            if await self.episode(episode_id) is None:
                raise EpisodeNotFoundError(episode_id)
            raise NothingToUndoError(episode_id)
        if history[-1].seq != expected_seq:
            raise await self._refusal(episode_id)
        before = history[-2].decision if len(history) > 1 else None
        previous = next((known for known in REVIEW_DECISIONS if known == before), None)
        return await self.decide(episode_id, expected_seq, previous, reason, reviewer)

    async def _refusal(self, episode_id: str) -> Exception:
        """Why a decision did not land: no such episode, or decided meanwhile."""
        episode = await self.episode(episode_id)
        if episode is None:
            return EpisodeNotFoundError(episode_id)
        history = await self.history(episode_id)
        return ReviewConflictError(episode, history[-1] if history else None)

    async def episode(self, episode_id: str) -> Episode | None:
        async with self.transactions() as db:
            return await db.get(Episode, episode_id)

    async def history(self, episode_id: str) -> list[ReviewDecisionRow]:
        """Every decision on the episode, first first."""
        statement = (
            select(ReviewDecisionRow)
            .where(ReviewDecisionRow.episode_id == episode_id)
            .order_by(ReviewDecisionRow.seq)
        )
        async with self.transactions() as db:
            return list(await db.scalars(statement))

    async def page(self, filters: ReviewFilters) -> ReviewPage:
        """One page of the episodes passing `filters`, in their order, and how many pass."""
        conditions = _conditions(filters)
        statement = select(Episode).where(*conditions)
        column = {
            "score": Episode.score,
            "created_at": Episode.created_at,
            "duration_s": Episode.duration_s,
        }[filters.sort]
        order = column.desc() if filters.descending else column.asc()
        tie = Episode.episode_id.desc() if filters.descending else Episode.episode_id.asc()
        statement = (
            statement.order_by(order.nulls_last(), tie).limit(filters.limit).offset(filters.offset)
        )
        count = select(func.count()).select_from(Episode).where(*conditions)
        async with self.transactions() as db:
            episodes = list(await db.scalars(statement))
            total = await db.scalar(count)
        return ReviewPage(episodes, total or 0)


def _conditions(f: ReviewFilters) -> list[ColumnElement[bool]]:
    """What an episode passing the filters satisfies."""
    conditions: list[ColumnElement[bool]] = []
    if f.task is not None:
        conditions.append(Episode.task == f.task)
    if f.worker is not None:
        conditions.append(Episode.worker_id == f.worker)
    if f.outcome is not None:
        conditions.append(Episode.outcome == f.outcome)
    if f.decision == "undecided":
        conditions.append(Episode.decision.is_(None))
    elif f.decision is not None:
        conditions.append(Episode.decision == f.decision)
    if f.flagged is not None:
        text = cast(Episode.flags, String)
        has_flags = Episode.flags.is_not(None) & text.not_in(UNFLAGGED)
        conditions.append(has_flags if f.flagged else ~has_flags)
    if f.score_min is not None:
        conditions.append(Episode.score >= f.score_min)
    if f.score_max is not None:
        conditions.append(Episode.score <= f.score_max)
    return conditions


class _LostRaceError(Exception):
    """The conditional update matched nothing: decided meanwhile, or no such episode."""
