"""Dating a client's messages on the server's clock: the offset from ping / pong round trips
(the fastest one wins, queueing only adds delay), and a message's age from it."""

from __future__ import annotations

import pytest

from crowdteleop.teleop.client_clock import ClientClock


def test_nothing_is_known_before_the_first_round_trip():
    assert ClientClock().age_ms(1_700_000_000_000.0, now_s=100.0) is None


def test_the_offset_comes_from_the_fastest_round_trip():
    clock = ClientClock()
    true_offset_ms = 1_700_000_000_000.0 - 100_000.0  # client wall clock vs server monotonic
    # a slow round trip whose reply sat 300 ms in a queue on the way back: off by 150 ms
    clock.add_round_trip(100.0, 100.34, 100_040.0 + true_offset_ms)
    # a fast one: 20 ms there and back, answered in the middle
    clock.add_round_trip(101.0, 101.02, 101_010.0 + true_offset_ms)
    assert clock.best is not None and clock.best.rtt_ms == pytest.approx(20.0)
    assert clock.best.offset_ms == pytest.approx(true_offset_ms, abs=1e-3)


def test_a_message_stamped_two_seconds_ago_is_two_seconds_old():
    clock = ClientClock()
    offset_ms = 5_000_000.0
    clock.add_round_trip(10.0, 10.01, 10_005.0 + offset_ms)
    stamped = 12_000.0 + offset_ms  # the client's clock at server time 12.0 s
    assert clock.age_ms(stamped, now_s=14.0) == pytest.approx(2000.0, abs=0.01)
    assert clock.age_ms(stamped, now_s=12.0) == pytest.approx(0.0, abs=0.01)


def test_old_round_trips_age_out_as_the_clocks_drift():
    clock = ClientClock()
    clock.add_round_trip(0.0, 0.001, 0.5)  # very fast, long ago
    for k in range(1, 17):
        clock.add_round_trip(float(k), k + 0.02, k * 1e3 + 10.0 + 1000.0)
    assert clock.best is not None and clock.best.offset_ms == pytest.approx(1000.0, abs=1e-6)


def test_the_age_is_known_to_within_half_the_best_round_trip():
    clock = ClientClock()
    assert clock.uncertainty_ms() == 0.0
    clock.add_round_trip(sent_s=10.0, received_s=10.8, client_ms=5_000.0)  # a slow 800 ms one
    assert clock.uncertainty_ms() == pytest.approx(400.0)
    clock.add_round_trip(sent_s=11.0, received_s=11.02, client_ms=6_010.0)
    assert clock.uncertainty_ms() == pytest.approx(10.0), "a faster round trip narrows it"
