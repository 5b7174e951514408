"""The admin page's charts: demonstrations, queue length and wait, live sessions, latency
and quality scores over the last hours, in fixed bins.

Derived from the database rather than sampled in memory: sessions keep when they were
queued, admitted and ended, episodes when they were reported, so the charts survive a
restart and every replica of the coordinator draws the same ones. One approximation: a
session whose teleop server failed is queued again with new `queued_at`/`admitted_at`, so
only its latest wait in the queue is seen (its earlier time counts as live)."""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from crowdteleop.coord.db.history import EpisodeFigures, HistoryStore, SessionTimes
from crowdteleop.coord.db.store import Store

SCORE_BIN = 10.0  # the score histogram's bins: 0-10, 10-20, ..., 90-100
LATENCIES = ("latency_p50_ms", "latency_p95_ms")


@dataclass(frozen=True)
class ChartBin:
    """One bin of the time charts; the means are over time (a queue of 2 for half the bin and
    0 for the rest: 1.0), the last bin's over the part that has passed."""

    start_s: float
    episodes: int
    successes: int
    queue_length_mean: float
    queue_length_max: int
    queue_wait_s_median: float | None  # of the waits that ended in the bin
    queue_wait_s_max: float | None
    live_sessions_mean: float
    live_sessions_max: int
    latency_p50_ms: float | None  # median over the bin's episodes of each one's p50
    latency_p95_ms: float | None  # and of each one's p95


@dataclass(frozen=True)
class ScoreBin:
    score_from: float
    score_to: float
    demonstrations: int


@dataclass(frozen=True)
class Charts:
    now_s: float
    bin_s: float
    bins: list[ChartBin]
    scores: list[ScoreBin]
    unscored: int  # successful episodes without a score (reported unmeasured)


class History:
    """Reads the last hours from the database and bins them; holds no state of its own."""

    def __init__(self, store: Store) -> None:
        self._rows = HistoryStore(store.transactions)

    async def charts(self, hours: float, bin_s: float, now: float | None = None) -> Charts:
        now = time.time() if now is None else now
        starts = bin_starts(now, hours, bin_s)
        sessions = await self._rows.sessions_since(starts[0])
        episodes = await self._rows.episodes_since(starts[0])
        return bin_history(sessions, episodes, starts, bin_s, now)


def bin_starts(now: float, hours: float, bin_s: float) -> list[float]:
    """Clock-aligned bins covering the last `hours`, oldest first; the last holds `now`."""
    count = max(1, math.ceil(hours * 3600.0 / bin_s))
    current = now - now % bin_s
    return [current - (count - 1 - i) * bin_s for i in range(count)]


def bin_history(
    sessions: Sequence[SessionTimes],
    episodes: Sequence[EpisodeFigures],
    starts: Sequence[float],
    bin_s: float,
    now: float,
) -> Charts:
    queued = [queued_interval(s, now) for s in sessions]
    live = [live_interval(s, now) for s in sessions]
    waits = [(end, end - start) for start, end in queued if end < now]
    bins = []
    for start in starts:
        end = min(start + bin_s, now)
        inside = [e for e in episodes if start <= e.created_at < start + bin_s]
        queue_mean, queue_max = occupancy(queued, start, end)
        live_mean, live_max = occupancy(live, start, end)
        ended_waits = [wait for at, wait in waits if start <= at < start + bin_s]
        bins.append(
            ChartBin(
                start_s=start,
                episodes=len(inside),
                successes=sum(e.outcome == "success" for e in inside),
                queue_length_mean=round(queue_mean, 3),
                queue_length_max=queue_max,
                queue_wait_s_median=_rounded(_median(ended_waits), 1),
                queue_wait_s_max=_rounded(max(ended_waits, default=None), 1),
                live_sessions_mean=round(live_mean, 3),
                live_sessions_max=live_max,
                latency_p50_ms=_rounded(_median(latencies(inside, LATENCIES[0])), 1),
                latency_p95_ms=_rounded(_median(latencies(inside, LATENCIES[1])), 1),
            )
        )
    successes = [e for e in episodes if e.outcome == "success"]
    scored = [e.score for e in successes if e.score is not None]
    return Charts(now, bin_s, bins, score_histogram(scored), len(successes) - len(scored))


def queued_interval(session: SessionTimes, now: float) -> tuple[float, float]:
    """From joining the queue to admission, or to leaving it (or to `now`, still waiting)."""
    start = session.queued_at if session.queued_at is not None else session.created_at
    end = session.admitted_at if session.admitted_at is not None else session.ended_at
    return start, max(start, end if end is not None else now)


def live_interval(session: SessionTimes, now: float) -> tuple[float, float]:
    """From admission to the end (or `now`); empty for a session never admitted."""
    if session.admitted_at is None:
        return now, now
    end = session.ended_at if session.ended_at is not None else now
    return session.admitted_at, max(session.admitted_at, end)


def occupancy(
    intervals: Iterable[tuple[float, float]], start: float, end: float
) -> tuple[float, int]:
    """How many of `intervals` were open in [start, end): the mean over time, and the most at
    once (an interval ending as another begins does not overlap it)."""
    inside = [(max(s, start), min(e, end)) for s, e in intervals if s < end and e > start and e > s]
    if end <= start:
        return 0.0, 0
    mean = sum(e - s for s, e in inside) / (end - start)
    level = peak = 0
    for _, change in sorted([(s, 1) for s, _ in inside] + [(e, -1) for _, e in inside]):
        level += change
        peak = max(peak, level)
    return mean, peak


def latencies(episodes: Iterable[EpisodeFigures], name: str) -> list[float]:
    """Each episode's latency figure `name`: its quality metrics', else its telemetry's; 0 or
    absent is unknown (no client reported any), not instant."""
    found = []
    for episode in episodes:
        value: Any = (episode.metrics or {}).get(name, episode.telemetry.get(name))
        if isinstance(value, int | float) and value > 0:
            found.append(float(value))
    return found


def score_histogram(scores: Iterable[float]) -> list[ScoreBin]:
    """Scores (0-100) in bins of SCORE_BIN; 100 itself falls in the last."""
    count = math.ceil(100.0 / SCORE_BIN)
    counts = [0] * count
    for score in scores:
        counts[min(count - 1, max(0, int(score // SCORE_BIN)))] += 1
    return [
        ScoreBin(i * SCORE_BIN, min(100.0, (i + 1) * SCORE_BIN), n) for i, n in enumerate(counts)
    ]


def _median(values: list[float]) -> float | None:
    return statistics.median(values) if values else None


def _rounded(value: float | None, digits: int) -> float | None:
    return None if value is None else round(value, digits)
