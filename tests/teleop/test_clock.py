"""The control loop's clock (crowdteleop.teleop.clock): a fixed rate, skipping rather than
bursting after a long tick."""

from __future__ import annotations

import asyncio
import time

import pytest

from crowdteleop.teleop.clock import FixedRateClock

pytestmark = pytest.mark.exclusive  # runs alone under xdist: a fixed-rate clock, timed


def test_the_clock_keeps_its_rate_and_skips_rather_than_bursts():
    async def run():
        clock = FixedRateClock(50.0)
        started = time.monotonic()
        for tick in range(10):
            due = await clock.wait_next()
            if tick == 3:
                await asyncio.sleep(0.07)  # a long tick: 3.5 periods
            clock.finished(due)
        return clock.stats, time.monotonic() - started

    stats, elapsed = asyncio.run(run())
    assert stats.overruns == 1
    assert stats.skipped >= 2
    assert elapsed == pytest.approx(0.02 * (9 + stats.skipped), abs=0.03)
