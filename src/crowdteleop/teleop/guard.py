"""Admission of inbound messages: size, rate, validity. Everything refused is counted."""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field

from pydantic import BaseModel

from crowdteleop.teleop.protocol import ProtocolError, parse_inbound


@dataclass
class TokenBucket:
    """A peer may send `rate` messages per second on average and `burst` at once."""

    rate: float
    burst: int
    _tokens: float = field(init=False)
    _last: float = field(init=False)

    def __post_init__(self) -> None:
        self._tokens = float(self.burst)
        self._last = time.monotonic()

    def take(self) -> bool:
        now = time.monotonic()
        self._tokens = min(self.burst, self._tokens + (now - self._last) * self.rate)
        self._last = now
        if self._tokens < 1.0:
            return False
        self._tokens -= 1.0
        return True


@dataclass
class InboundGuard:
    """One per peer: turns raw data-channel payloads into validated messages or errors.

    Floods are refused before parsing, so a flood costs a bucket check, not a JSON parse.
    `errors` counts refusals by code; `accepted` counts the rest.
    """

    max_bytes: int
    rate: float
    burst: int
    errors: Counter[str] = field(default_factory=Counter)
    accepted: int = 0
    _bucket: TokenBucket = field(init=False)

    def __post_init__(self) -> None:
        self._bucket = TokenBucket(self.rate, self.burst)

    def admit(self, channel: str, raw: str | bytes) -> BaseModel:
        """The validated message; raises ProtocolError (already counted) otherwise."""
        try:
            if not self._bucket.take():
                raise ProtocolError(
                    "rate_limited", f"more than {self.rate:g} messages/s: message dropped"
                )
            message = parse_inbound(channel, raw, self.max_bytes)
        except ProtocolError as exc:
            self.errors[exc.code] += 1
            raise
        self.accepted += 1
        return message

    def refuse(self, code: str) -> None:
        """Count a refusal decided after parsing (stale, not in control, ...)."""
        self.errors[code] += 1
