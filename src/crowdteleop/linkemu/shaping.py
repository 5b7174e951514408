"""One direction of an emulated link, as Cellsim and Mahimahi model it: random loss on arrival,
a drop-tail queue in front of the link, the link's service (a constant rate, or a trace of
delivery opportunities), then a fixed one-way delay.

Pure arithmetic on packet sizes and times, so it is tested without any network; the
forwarder (`linkemu.forwarder`) feeds it the packets of a TUN device.
"""

from __future__ import annotations

import bisect
import random
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from pydantic import BaseModel, Field, model_validator

OPPORTUNITY_BYTES = 1504  # Mahimahi's: one MTU-sized packet (with its 4-byte TUN header)


class LinkSettings(BaseModel):
    """One direction. Rate and trace are exclusive; neither means no rate limit."""

    rate_bps: float | None = Field(None, gt=0, description="constant link rate")
    trace_ms: list[int] | None = Field(
        None,
        min_length=1,
        description="Mahimahi trace: the times of delivery opportunities, repeating",
    )
    delay_ms: float = Field(0.0, ge=0, description="one-way propagation delay")
    queue_bytes: int | None = Field(
        None, gt=0, description="drop-tail queue in front of the link; None: unbounded"
    )
    loss: float = Field(0.0, ge=0, lt=1, description="probability a packet is lost on arrival")
    seed: int = 0

    @model_validator(mode="after")
    def _one_service(self) -> LinkSettings:
        if self.rate_bps is not None and self.trace_ms is not None:
            raise ValueError("give rate_bps or trace_ms, not both")
        if self.trace_ms is not None:
            if any(b < a for a, b in zip(self.trace_ms, self.trace_ms[1:], strict=False)):
                raise ValueError("a trace's times must not decrease")
            if self.trace_ms[-1] <= 0:
                raise ValueError("a trace must last more than 0 ms")
        return self

    def mean_rate_bps(self) -> float | None:
        if self.trace_ms is not None:
            return len(self.trace_ms) * OPPORTUNITY_BYTES * 8 / (self.trace_ms[-1] / 1e3)
        return self.rate_bps


def read_mahimahi_trace(path: Path) -> list[int]:
    """One delivery opportunity per line, in ms since the trace began (Mahimahi's format)."""
    times = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        if line.strip():
            try:
                times.append(int(line))
            except ValueError:
                raise ValueError(f"{path}:{number}: not a time in ms: {line!r}") from None
    if not times:
        raise ValueError(f"{path}: an empty trace")
    return times


@dataclass
class Counters:
    packets_in: int = 0
    lost: int = 0  # random loss
    dropped: int = 0  # queue full
    cut: int = 0  # arrived while the link was cut
    delivered_bytes: int = 0


class TraceService:
    """When the bytes of each packet have been served by a trace's delivery opportunities.

    Each opportunity serves up to OPPORTUNITY_BYTES of whatever is queued; a packet leaves
    at the opportunity that serves its last byte; an opportunity nobody uses is lost."""

    def __init__(self, trace_ms: list[int]) -> None:
        self.trace_s = [t / 1e3 for t in trace_ms]
        self.period_s = trace_ms[-1] / 1e3
        self.index = -1  # the opportunity that served the last byte so far
        self.credit = 0  # what that opportunity can still serve

    def _time(self, index: int) -> float:
        cycle, offset = divmod(index, len(self.trace_s))
        return cycle * self.period_s + self.trace_s[offset]

    def _first_at_or_after(self, when_s: float) -> int:
        cycle = int(when_s // self.period_s)
        offset = bisect.bisect_left(self.trace_s, when_s - cycle * self.period_s)
        return cycle * len(self.trace_s) + offset

    def departure_s(self, arrival_s: float, size: int) -> float:
        if self.index < 0 or self.credit == 0 or self._time(self.index) < arrival_s:
            self.index = max(self._first_at_or_after(arrival_s), self.index + 1)
            self.credit = OPPORTUNITY_BYTES
        remaining = size
        while True:
            served = min(self.credit, remaining)
            remaining -= served
            self.credit -= served
            if remaining == 0:
                return self._time(self.index)
            self.index += 1
            self.credit = OPPORTUNITY_BYTES


class Direction:
    """`push` a packet as it arrives; it returns when the packet reaches the far side, or None
    if the link lost or dropped it."""

    def __init__(self, settings: LinkSettings) -> None:
        self.settings = settings
        self.counters = Counters()
        self._rng = random.Random(settings.seed)
        self._in_queue: deque[tuple[float, int]] = deque()  # (departure_s, size) not yet left
        self._queued_bytes = 0
        self._link_free_s = 0.0
        self._trace = TraceService(settings.trace_ms) if settings.trace_ms else None
        self.is_cut = False  # a cable pulled: everything arriving is lost until restored

    def queued_bytes(self, now_s: float) -> int:
        while self._in_queue and self._in_queue[0][0] <= now_s:
            self._queued_bytes -= self._in_queue.popleft()[1]
        return self._queued_bytes

    def push(self, size: int, now_s: float) -> float | None:
        settings, counters = self.settings, self.counters
        counters.packets_in += 1
        if self.is_cut:
            counters.cut += 1
            return None
        if settings.loss and self._rng.random() < settings.loss:
            counters.lost += 1
            return None
        limit = settings.queue_bytes
        if limit is not None and self.queued_bytes(now_s) + size > limit:
            counters.dropped += 1
            return None
        if self._trace is not None:
            departure = self._trace.departure_s(now_s, size)
        elif settings.rate_bps is not None:
            start = max(now_s, self._link_free_s)
            departure = start + size * 8 / settings.rate_bps
        else:
            departure = now_s
        self._link_free_s = departure
        self._in_queue.append((departure, size))
        self._queued_bytes += size
        counters.delivered_bytes += size
        return departure + settings.delay_ms / 1e3
