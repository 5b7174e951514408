"""Figures for the admin page: demonstrations per hour, completion times per worker/interface."""

from __future__ import annotations

import statistics
from collections import defaultdict
from collections.abc import Callable, Iterable

from crowdteleop.coord.api.schemas import DurationSummary, HourCount
from crowdteleop.coord.db.tables import Episode

HOUR = 3600.0


def per_hour(episodes: Iterable[Episode], now: float, hours: int = 24) -> list[HourCount]:
    """Episodes and successes in each of the last `hours` clock hours, oldest first."""
    current = now - now % HOUR
    first = current - (hours - 1) * HOUR
    counts = {first + i * HOUR: [0, 0] for i in range(hours)}
    for episode in episodes:
        bucket = episode.created_at - episode.created_at % HOUR
        if bucket in counts:
            counts[bucket][0] += 1
            counts[bucket][1] += episode.outcome == "success"
    return [HourCount(hour_start=h, episodes=e, successes=s) for h, (e, s) in counts.items()]


def completion_times(
    episodes: Iterable[Episode], key: Callable[[Episode], str | None]
) -> list[DurationSummary]:
    """Per key: how long successful episodes took (the paper's completion time)."""
    groups: dict[str, list[Episode]] = defaultdict(list)
    for episode in episodes:
        groups[key(episode) or "unknown"].append(episode)
    summaries = []
    for name, group in sorted(groups.items()):
        times = [e.duration_s for e in group if e.outcome == "success"]
        summaries.append(
            DurationSummary(
                key=name,
                successes=len(times),
                episodes=len(group),
                mean_s=round(statistics.fmean(times), 2) if times else None,
                median_s=round(statistics.median(times), 2) if times else None,
                min_s=round(min(times), 2) if times else None,
                max_s=round(max(times), 2) if times else None,
            )
        )
    return summaries
