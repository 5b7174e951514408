"""The emulated link does what its settings say, measured by tools that are not ours: iperf3
for rate and loss, timestamps on datagrams for the one-way delay. Done when: rate within 5 %,
delay within 2 ms, loss within 1 percentage point."""

from __future__ import annotations

import os
import shutil
import statistics

import pytest

from crowdteleop.linkemu.measure import (
    PROBE_BYTES,
    iperf_udp,
    lost_percent,
    one_way_delays_ms,
    wire_rate_bps,
)
from crowdteleop.linkemu.netns import emulated_link
from crowdteleop.linkemu.shaping import LinkSettings

pytestmark = [
    pytest.mark.slow,
    pytest.mark.exclusive,
]  # runs alone under xdist: the link's delay and rate, measured
PAYLOAD = 1400


@pytest.fixture(autouse=True)
def _needs_root_and_iperf3() -> None:
    if os.geteuid() != 0:
        pytest.skip("namespaces and TUN devices need root (CI runs as root)")
    if shutil.which("iperf3") is None:
        pytest.fail("iperf3 is missing: `make test` installs it (scripts/system-deps.sh)")


@pytest.mark.parametrize("rate_bps", [2.4e6, 500e3])
def test_the_rate_is_the_setting_within_5_percent(rate_bps):
    settings = LinkSettings(rate_bps=rate_bps, delay_ms=20, queue_bytes=30_000)
    with emulated_link(settings, settings) as link:
        report = iperf_udp(link, offered_bps=rate_bps * 1.5, seconds=6, length=PAYLOAD)
        stats = link.stats()
    assert wire_rate_bps(report, PAYLOAD) == pytest.approx(rate_bps, rel=0.05)
    assert stats["up"]["dropped"] > 0, "offered 1.5 x the rate, the queue overflowed"


def test_a_trace_gives_its_mean_rate_within_5_percent():
    # Mahimahi's format: one MTU-sized delivery opportunity every 5 ms = 2.4 Mbps
    settings = LinkSettings(trace_ms=list(range(5, 1001, 5)), queue_bytes=30_000)
    with emulated_link(settings, LinkSettings()) as link:
        report = iperf_udp(link, offered_bps=4e6, seconds=6, length=PAYLOAD)
    expected = settings.mean_rate_bps()
    assert expected is not None
    # as in Mahimahi, a packet's bytes may span opportunities, so a busy link uses them all
    assert wire_rate_bps(report, PAYLOAD) == pytest.approx(expected, rel=0.05)


def test_loss_is_the_setting_within_1_percentage_point():
    settings = LinkSettings(loss=0.02, seed=7)
    with emulated_link(settings, LinkSettings()) as link:
        report = iperf_udp(link, offered_bps=2e6, seconds=5, length=500)
    assert report["end"]["sum"]["packets"] > 2000
    assert lost_percent(report) == pytest.approx(2.0, abs=1.0)


@pytest.mark.parametrize("delay_ms", [20.0, 120.0])
def test_the_one_way_delay_is_the_setting_within_2_ms(delay_ms):
    settings = LinkSettings(rate_bps=2.4e6, delay_ms=delay_ms, queue_bytes=30_000)
    with emulated_link(settings, settings) as link:
        delays_ms = one_way_delays_ms(link, count=100)
    assert len(delays_ms) == 100, "no probe lost on a link without loss"
    serialization_ms = PROBE_BYTES * 8 / 2.4e6 * 1e3
    assert statistics.median(delays_ms) == pytest.approx(delay_ms + serialization_ms, abs=2.0)
