"""A fixed-rate loop against the wall clock, with drift correction and counted overruns."""

from __future__ import annotations

import asyncio
import statistics
import time
from collections import deque
from dataclasses import dataclass, field


@dataclass
class LoopStats:
    """What the loop did: ticks, overruns (ticks that ended after the next was due), slots
    skipped because a tick ran long, and recent tick start times for rate and jitter."""

    ticks: int = 0
    overruns: int = 0
    skipped: int = 0
    late: int = 0  # ticks that started half a period or more after their slot
    starts: deque[float] = field(default_factory=lambda: deque(maxlen=200))
    lateness: deque[float] = field(default_factory=lambda: deque(maxlen=200))

    def rate_hz(self) -> float:
        if len(self.starts) < 2:
            return 0.0
        span = self.starts[-1] - self.starts[0]
        return (len(self.starts) - 1) / span if span > 0 else 0.0

    def jitter_ms(self) -> float:
        """Standard deviation of how late ticks started, in milliseconds."""
        if len(self.lateness) < 2:
            return 0.0
        return statistics.pstdev(self.lateness) * 1e3

    def on_time_fraction(self, period: float) -> float:
        """Ticks that started within half a period of their slot."""
        if not self.lateness:
            return 1.0
        return sum(1 for late in self.lateness if late < period / 2) / len(self.lateness)


class FixedRateClock:
    """Tick k is due at start + k * period. Sleep error never accumulates; a tick that runs
    long makes the next start at once, and slots missed entirely are skipped (a live session
    drops frames rather than bursting to catch up)."""

    def __init__(self, rate_hz: float) -> None:
        self.period = 1.0 / rate_hz
        self.stats = LoopStats()
        self._start: float | None = None
        self._index = 0

    def restart(self) -> None:
        self._start = None

    async def wait_next(self) -> float:
        """Sleep until the next tick is due; returns its due time (monotonic seconds)."""
        now = time.monotonic()
        if self._start is None:
            self._start, self._index = now, 0
        else:
            self._index += 1
            due = self._start + self._index * self.period
            if now > due + self.period:  # a whole slot passed: skip, don't burst
                missed = int((now - due) / self.period)
                self.stats.skipped += missed
                self._index += missed
        due = self._start + self._index * self.period
        if due > now:
            await asyncio.sleep(due - now)
        started = time.monotonic()
        self.stats.ticks += 1
        self.stats.starts.append(started)
        self.stats.lateness.append(max(0.0, started - due))
        if started - due >= self.period / 2:
            self.stats.late += 1
        return due

    def finished(self, due: float) -> None:
        """Call when a tick's work is done: counts an overrun if it ended past the next slot."""
        if time.monotonic() > due + self.period:
            self.stats.overruns += 1
