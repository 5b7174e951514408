"""One direction of the emulated link, on paper: loss, drop-tail queue, rate, trace, delay."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from crowdteleop.linkemu.shaping import (
    OPPORTUNITY_BYTES,
    Direction,
    LinkSettings,
    read_mahimahi_trace,
)

pytestmark = pytest.mark.exclusive  # runs alone under xdist: the link's delay and rate, measured


def test_a_constant_rate_serializes_packets_back_to_back_then_adds_the_delay():
    link = Direction(LinkSettings(rate_bps=8_000_000, delay_ms=20))  # 1 byte per µs
    assert link.push(1000, 0.0) == pytest.approx(0.001 + 0.020)
    assert link.push(1000, 0.0) == pytest.approx(0.002 + 0.020), "queued behind the first"
    assert link.push(1000, 0.5) == pytest.approx(0.501 + 0.020), "an idle link starts at once"


def test_a_full_drop_tail_queue_drops_the_newcomer_until_it_drains():
    link = Direction(LinkSettings(rate_bps=8_000_000, queue_bytes=2500))
    assert link.push(1000, 0.0) is not None
    assert link.push(1000, 0.0) is not None
    assert link.push(1000, 0.0) is None, "2000 queued + 1000 > 2500"
    assert link.counters.dropped == 1
    assert link.push(1000, 0.0011) is not None, "the first has left"


def test_random_loss_loses_its_share_of_packets():
    link = Direction(LinkSettings(loss=0.02, seed=1))
    lost = sum(link.push(100, i * 1e-3) is None for i in range(50_000))
    assert lost / 50_000 == pytest.approx(0.02, abs=0.002)
    assert link.counters.lost == lost


def test_a_trace_delivers_one_mtu_per_line_and_repeats():
    # opportunities at 5 and 10 ms, repeating every 10 ms: 2 x 1504 B per 10 ms
    link = Direction(LinkSettings(trace_ms=[5, 10], delay_ms=1))
    assert link.push(1500, 0.0) == pytest.approx(0.005 + 0.001)
    assert link.push(1500, 0.0) == pytest.approx(0.010 + 0.001)
    assert link.push(1500, 0.0) == pytest.approx(0.015 + 0.001), "the trace repeats"
    assert link.settings.mean_rate_bps() == pytest.approx(2 * OPPORTUNITY_BYTES * 8 / 0.010)


def test_small_packets_share_an_opportunity_and_an_unused_one_is_lost():
    link = Direction(LinkSettings(trace_ms=[10]))
    assert link.push(700, 0.0) == pytest.approx(0.010)
    assert link.push(700, 0.001) == pytest.approx(0.010), "804 bytes of it were left"
    assert link.push(700, 0.002) == pytest.approx(0.020), "the rest did not fit"
    assert link.push(100, 0.035) == pytest.approx(0.040), "the idle 30 ms served nobody"


def test_settings_refuse_what_makes_no_link(tmp_path):
    with pytest.raises(ValidationError, match="not both"):
        LinkSettings(rate_bps=1e6, trace_ms=[1])
    with pytest.raises(ValidationError, match="must not decrease"):
        LinkSettings(trace_ms=[5, 3])
    with pytest.raises(ValidationError):
        LinkSettings(loss=1.5)
    trace = tmp_path / "bad.trace"
    trace.write_text("1\n2\nthree\n")
    with pytest.raises(ValueError, match=r"bad\.trace:3"):
        read_mahimahi_trace(trace)
    trace.write_text("3\n3\n7\n")
    assert read_mahimahi_trace(trace) == [3, 3, 7]


def test_a_cut_link_loses_everything_until_restored():
    link = Direction(LinkSettings(rate_bps=8_000_000))
    link.is_cut = True
    assert link.push(1000, 0.0) is None
    assert link.counters.cut == 1
    link.is_cut = False
    assert link.push(1000, 0.1) == pytest.approx(0.101)
