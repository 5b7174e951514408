"""The inbound guard (crowdteleop.teleop.guard): size and rate limits, counted refusals."""

from __future__ import annotations

import json

from crowdteleop.teleop.guard import InboundGuard
from crowdteleop.teleop.protocol import ProtocolError
from tests.fixtures.poses import POSE


def test_the_guard_counts_refusals_and_limits_floods():
    guard = InboundGuard(max_bytes=4096, rate=5, burst=3)
    accepted = 0
    for _ in range(10):
        try:
            guard.admit("control", json.dumps(POSE))
            accepted += 1
        except ProtocolError:
            pass
    assert accepted == 3
    assert guard.errors["rate_limited"] == 7
