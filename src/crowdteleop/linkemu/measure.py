"""Measuring an emulated link with tools that are not the emulator: iperf3 (rate, loss) and
timestamped datagrams (`linkemu.probe`, one-way delay)."""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time
from typing import Any

from crowdteleop.linkemu.netns import EmulatedLink

UDP_IP_HEADERS = 28
PROBE_BYTES = 128  # the probe's datagram on the wire (100 B of padding, stamp, headers)


def iperf_udp(link: EmulatedLink, offered_bps: float, seconds: int, length: int) -> dict[str, Any]:
    """The receiver's report (iperf3's JSON, server side) of a UDP stream from A to B."""
    server = subprocess.Popen(
        link.run_in("b", ["iperf3", "-s", "-1", "-B", link.address_b, "--json"]),
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        time.sleep(0.5)
        client = [
            "iperf3", "-c", link.address_b, "-u", "-b", str(int(offered_bps)),
            "-l", str(length), "-t", str(seconds), "--json",
        ]  # fmt: skip
        subprocess.run(link.run_in("a", client), check=True, capture_output=True, timeout=60)
        out, _ = server.communicate(timeout=30)
    finally:
        server.kill()
    report: dict[str, Any] = json.loads(out)
    return report


def wire_rate_bps(report: dict[str, Any], length: int) -> float:
    """The steady receiving rate on the wire: the median of iperf3's 1 s intervals but the
    first and last (the queue fills, then drains), payload plus UDP/IP headers."""
    rates = [interval["sum"]["bits_per_second"] for interval in report["intervals"][1:-1]]
    return float(statistics.median(rates)) * (length + UDP_IP_HEADERS) / length


def lost_percent(report: dict[str, Any]) -> float:
    return float(report["end"]["sum"]["lost_percent"])


def one_way_delays_ms(
    link: EmulatedLink, count: int = 100, interval_s: float = 0.02
) -> list[float]:
    """Each probe datagram's arrival time in B minus its send time in A (one clock)."""
    probe = [sys.executable, "-m", "crowdteleop.linkemu.probe"]
    receiver = subprocess.Popen(
        link.run_in("b", [*probe, "receive", link.address_b, "9400", str(count)]),
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert receiver.stdout is not None
        if receiver.stdout.readline().strip() != "listening":
            raise RuntimeError("the delay probe's receiver did not start")
        sender = [*probe, "send", link.address_b, "9400", str(count), str(interval_s)]
        subprocess.run(link.run_in("a", sender), check=True, timeout=60)
        delays: list[float] = json.loads(receiver.communicate(timeout=30)[0])
    finally:
        receiver.kill()
    return delays
