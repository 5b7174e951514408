"""Each worker's record (demonstrations, success, scores, review decisions, flags, time) and
their reputation; blocking a worker; their bonus files (docs/workers.md).

The reputation (0-100) answers "how far can this worker's next demonstration be trusted":

    acceptance = (accepted + K * p0) / (decided + K)          K = 5
    quality    = (n * median_score + K * mu) / (n + K)        n = scored demonstrations
    reputation = 60 * acceptance + 0.4 * quality

- `p0` is the campaign's acceptance rate over every decided episode (0.5 before any), `mu`
  the median score of its scored demonstrations (50 before any). Both parts are Bayesian
  posterior means with a prior worth K = 5 observations, so a worker with one lucky accept
  or one brilliant demonstration does not top the table, and a newcomer sits at the
  campaign's middle rather than at zero. (A Wilson lower bound would rank every newcomer
  last, which punishes joining late; the shrinkage already keeps a few figures from
  deciding alone.)
- Acceptance weighs more (60 of 100) than the score: it is a person's verdict, or the
  campaign's rule where the score was clear, while the score is a percentile against the
  crowd, which moves as the crowd grows.
"""

from __future__ import annotations

import statistics
import time
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from crowdteleop.coord.db.store import Store
from crowdteleop.coord.db.tables import Episode, Worker
from crowdteleop.coord.db.worker_stats import WorkerStatsStore
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.service.bonus import BonusFormat, bonus_file
from crowdteleop.coord.service.coordinator import Coordinator
from crowdteleop.coord.service.metrics import CoordMetrics

PRIOR_WEIGHT = 5.0  # K: the prior counts as this many decisions / demonstrations
ACCEPTANCE_WEIGHT = 0.6  # of the reputation; the rest is the (shrunk) median score


@dataclass(frozen=True)
class WorkerStats:
    """One worker's figures over a set of episodes."""

    episodes: int
    demonstrations: int  # successful episodes
    success_rate: float | None
    median_score: float | None  # of the scored demonstrations
    scored: int
    accepted: int
    rejected: int
    undecided: int  # demonstrations without a decision
    acceptance_rate: float | None  # accepted / decided
    flags: dict[str, int] = field(default_factory=dict)  # flag counts by metric
    median_time_s: float | None = None  # per demonstration


@dataclass(frozen=True)
class CampaignPrior:
    """What a worker with few figures is shrunk toward: the campaign's own middle."""

    acceptance: float = 0.5
    score: float = 50.0


@dataclass(frozen=True)
class WorkerRecord:
    worker: Worker
    stats: WorkerStats
    reputation: float


def _median(values: Sequence[float]) -> float | None:
    return round(statistics.median(values), 2) if values else None


def _rate(part: int, whole: int) -> float | None:
    return round(part / whole, 4) if whole else None


def worker_stats(episodes: Sequence[Episode]) -> WorkerStats:
    """The figures of one worker's episodes."""
    successes = [e for e in episodes if e.outcome == "success"]
    scores = [e.score for e in successes if e.score is not None]
    accepted = sum(e.decision == "accepted" for e in episodes)
    rejected = sum(e.decision == "rejected" for e in episodes)
    flags = Counter(flag["metric"] for e in episodes for flag in e.flags or [] if "metric" in flag)
    return WorkerStats(
        episodes=len(episodes),
        demonstrations=len(successes),
        success_rate=_rate(len(successes), len(episodes)),
        median_score=_median(scores),
        scored=len(scores),
        accepted=accepted,
        rejected=rejected,
        undecided=sum(e.decision is None for e in successes),
        acceptance_rate=_rate(accepted, accepted + rejected),
        flags=dict(sorted(flags.items())),
        median_time_s=_median([e.duration_s for e in successes]),
    )


def campaign_prior(episodes: Iterable[Episode]) -> CampaignPrior:
    """The campaign's acceptance rate and median score, over every worker's episodes."""
    decisions = [e.decision for e in episodes if e.decision is not None]
    scores = [e.score for e in episodes if e.outcome == "success" and e.score is not None]
    default = CampaignPrior()
    return CampaignPrior(
        acceptance=decisions.count("accepted") / len(decisions)
        if decisions
        else default.acceptance,
        score=statistics.median(scores) if scores else default.score,
    )


def reputation(stats: WorkerStats, prior: CampaignPrior) -> float:
    """0-100: the module's formula."""
    decided = stats.accepted + stats.rejected
    acceptance = (stats.accepted + PRIOR_WEIGHT * prior.acceptance) / (decided + PRIOR_WEIGHT)
    median = stats.median_score if stats.median_score is not None else prior.score
    quality = (stats.scored * median + PRIOR_WEIGHT * prior.score) / (stats.scored + PRIOR_WEIGHT)
    value = 100 * ACCEPTANCE_WEIGHT * acceptance + (1 - ACCEPTANCE_WEIGHT) * quality
    return round(min(100.0, max(0.0, value)), 1)


class WorkerRecords:
    """The workers page's service: records, reputations, blocking."""

    def __init__(self, store: Store, coordinator: Coordinator, metrics: CoordMetrics) -> None:
        self._stats = WorkerStatsStore(store.transactions)
        self._sessions = store.sessions
        self._coordinator, self._metrics = coordinator, metrics

    async def records(self, campaign: str | None = None) -> list[WorkerRecord]:
        """Every worker's record (of `campaign`'s sessions, if given), oldest worker first."""
        workers = await self._stats.workers(campaign)
        episodes = await self._stats.episodes(campaign=campaign)
        prior = campaign_prior(episodes)
        by_worker: dict[str, list[Episode]] = defaultdict(list)
        for episode in episodes:
            by_worker[episode.worker_id].append(episode)
        records = []
        for worker in workers:
            stats = worker_stats(by_worker[worker.id])
            records.append(WorkerRecord(worker, stats, reputation(stats, prior)))
        return records

    async def record(self, worker_id: str) -> tuple[WorkerRecord, list[Episode]]:
        """One worker's record against the campaign of their last link, and their episodes
        (404 for an unknown worker)."""
        worker = await self._existing(worker_id)
        prior = campaign_prior(await self._stats.episodes(campaign=worker.campaign))
        episodes = await self._stats.episodes([worker.id])
        stats = worker_stats(episodes)
        return WorkerRecord(worker, stats, reputation(stats, prior)), episodes

    async def block(self, worker_id: str, reason: str) -> Worker:
        """Block a worker: their joins and new sessions are refused, their live session ends."""
        worker = await self._stats.set_blocked(worker_id, time.time(), reason)
        if worker is None:
            raise ApiError(404, "not_found", "no such worker")
        self._metrics.blocks.inc()
        live = await self._sessions.live_session_of(worker_id)
        if live is not None:
            await self._coordinator.end(live.id, "error", error="blocked by an admin")
        return worker

    async def unblock(self, worker_id: str) -> Worker:
        worker = await self._stats.set_blocked(worker_id, None, None)
        if worker is None:
            raise ApiError(404, "not_found", "no such worker")
        return worker

    async def bonus(self, campaign: str, platform: BonusFormat, per_accepted: float) -> str:
        """The bonus file of `campaign`'s accepted demonstrations for `platform` (bonus.py)."""
        return await bonus_file(self._stats, campaign, platform, per_accepted)

    async def _existing(self, worker_id: str) -> Worker:
        worker = await self._stats.worker(worker_id)
        if worker is None:
            raise ApiError(404, "not_found", "no such worker")
        return worker
