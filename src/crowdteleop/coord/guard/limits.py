"""Rate limits that cost O(1) per request, whatever the number of clients.

Each key keeps the times of its last `limit` events (never more: a refused event is not
stored), so "at most `limit` in any `window_s`" is exact. Keys live in an LRU order; each call
forgets the least recently active keys whose events have all left the window, a few at a time,
so a flood of new addresses never makes one request scan the table (the old limiter's prune
cost 42 ms of event loop per new address at 100k addresses). Kept in this process's memory: a
coordinator restart forgets them (docs/security.md).
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict, deque
from dataclasses import dataclass, field

FORGET_PER_CALL = 4  # stale keys dropped per call: amortized O(1), and the table still drains


@dataclass
class WindowLimiter:
    """At most `limit` events per key in any `window_s`. Past `max_keys` keys the least
    recently active one is forgotten (memory stays bounded; the total limit still holds)."""

    limit: int
    window_s: float = 60.0
    max_keys: int = 100_000
    _events: OrderedDict[str, deque[float]] = field(default_factory=OrderedDict, repr=False)

    def _forget_stale(self, now: float) -> None:
        for _ in range(FORGET_PER_CALL):
            if not self._events:
                return
            key, events = next(iter(self._events.items()))
            if events and events[-1] > now - self.window_s:
                return  # the least recently active key is still in the window: all are
            del self._events[key]

    def _recent(self, key: str, now: float) -> deque[float]:
        events = self._events.get(key)
        if events is None:
            return deque()
        while events and events[0] <= now - self.window_s:
            events.popleft()
        return events

    def wait_s(self, key: str, now: float | None = None) -> float:
        """Seconds until `key` may have another event (0: now)."""
        now = time.monotonic() if now is None else now
        self._forget_stale(now)
        events = self._recent(key, now)
        if len(events) < self.limit:
            return 0.0
        return max(0.0, events[0] + self.window_s - now)

    def hit(self, key: str, now: float | None = None) -> None:
        """Count one event of `key` (at most the last `limit` are kept)."""
        now = time.monotonic() if now is None else now
        events = self._recent(key, now)
        if key not in self._events:
            if len(self._events) >= self.max_keys:
                self._events.popitem(last=False)
            self._events[key] = events
        else:
            self._events.move_to_end(key)
        events.append(now)
        if len(events) > self.limit:
            events.popleft()

    def take(self, key: str, now: float | None = None) -> float:
        """Count one event if allowed: 0.0; else the seconds to wait (nothing counted)."""
        now = time.monotonic() if now is None else now
        wait = self.wait_s(key, now)
        if wait == 0.0:
            self.hit(key, now)
        return wait


def retry_after(wait_s: float) -> dict[str, str]:
    """The `Retry-After` header for a refusal that lasts `wait_s`."""
    return {"Retry-After": str(max(1, math.ceil(wait_s)))}
