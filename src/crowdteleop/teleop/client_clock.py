"""How old a client's message is, on the server's clock.

Poses carry ``client_time_ms``, the client's wall clock, which may be off from the server's
by any amount. The server's periodic ``ping`` (its monotonic time) comes back as a ``pong``
stamped with the client's clock, so each round trip gives the offset between the clocks to
within half its RTT (NTP's estimate). The sample with the smallest RTT among the recent ones
is the most accurate: queueing only ever adds delay, so it is the one used.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

SAMPLES = 16  # recent round trips kept: the clocks drift, a stale minimum must age out


@dataclass(frozen=True)
class OffsetSample:
    offset_ms: float  # client clock minus server clock at the same instant
    rtt_ms: float


@dataclass
class ClientClock:
    """One peer's clock offset, from its pongs."""

    samples: deque[OffsetSample] = field(default_factory=lambda: deque(maxlen=SAMPLES))
    best: OffsetSample | None = None  # the fastest of `samples`, kept as they change

    def add_round_trip(self, sent_s: float, received_s: float, client_ms: float) -> None:
        """A ping sent at ``sent_s`` (server monotonic seconds) came back at ``received_s``,
        stamped ``client_ms`` by the client when it answered."""
        rtt_ms = max(0.0, (received_s - sent_s) * 1e3)
        midpoint_ms = (sent_s + received_s) / 2 * 1e3
        self.samples.append(OffsetSample(client_ms - midpoint_ms, rtt_ms))
        # once a round trip, not once a pose: `age_ms` runs for every pose that arrives
        self.best = min(self.samples, key=lambda s: s.rtt_ms)

    def age_ms(self, client_time_ms: float, now_s: float) -> float | None:
        """How long ago (server clock) the client stamped ``client_time_ms``; None before the
        first round trip (nothing is known of the client's clock yet). The error is at most
        half the best sample's RTT."""
        best = self.best
        if best is None:
            return None
        return now_s * 1e3 - (client_time_ms - best.offset_ms)

    def uncertainty_ms(self) -> float:
        """How far `age_ms` may be off: half the best round trip (0 before any)."""
        return self.best.rtt_ms / 2 if self.best is not None else 0.0
