"""Waiting-time estimates for the FIFO queue (pure functions, so they are easy to test)."""

from __future__ import annotations

import heapq
import statistics
from collections.abc import Sequence


def mean_session_s(observed: Sequence[float], fallback_s: float) -> float:
    """Mean of the observed session durations; the time limit until there are any."""
    durations = [d for d in observed if d > 0]
    return statistics.fmean(durations) if durations else fallback_s


def queue_etas(
    capacity: int, remaining_s: Sequence[float], waiting: int, mean_s: float
) -> list[float]:
    """Estimated wait of each of `waiting` queued sessions, first in line first.

    Each busy slot frees after its session's expected remaining time (`remaining_s`, one per
    busy slot); each queued session then holds the slot it takes for `mean_s`.
    """
    free_at = [max(0.0, r) for r in remaining_s][:capacity]
    free_at += [0.0] * (capacity - len(free_at))
    heapq.heapify(free_at)
    etas = []
    for _ in range(waiting):
        start = heapq.heappop(free_at)
        etas.append(round(start, 1))
        heapq.heappush(free_at, start + mean_s)
    return etas


def expected_remaining_s(elapsed_s: float, mean_s: float, time_limit_s: float) -> float:
    """How much longer a running session is expected to hold its slot."""
    expected_total = min(time_limit_s, max(mean_s, elapsed_s))
    return max(0.0, expected_total - elapsed_s)
