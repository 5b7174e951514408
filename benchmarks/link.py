"""The link emulator's accuracy against its settings (issue 15, item 3), measured by tools that
are not ours: iperf3 for rate and loss (UDP, receiver side), timestamped datagrams for the
one-way delay. Each setting is measured --runs times; the table gives medians and the worst run.

    sudo .venv/bin/python benchmarks/link.py --runs 3      # root: namespaces, TUN devices
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

from rich.console import Console
from rich.table import Table

from crowdteleop.linkemu.measure import (
    PROBE_BYTES,
    iperf_udp,
    lost_percent,
    one_way_delays_ms,
    wire_rate_bps,
)
from crowdteleop.linkemu.netns import emulated_link
from crowdteleop.linkemu.shaping import LinkSettings

PAYLOAD = 1400
QUEUE = 30_000


def rate_case(settings: LinkSettings) -> tuple[float, float]:
    with emulated_link(settings, LinkSettings()) as link:
        expected = settings.mean_rate_bps()
        assert expected is not None
        report = iperf_udp(link, offered_bps=expected * 1.5, seconds=6, length=PAYLOAD)
    return expected, wire_rate_bps(report, PAYLOAD)


def loss_case(loss: float, seed: int) -> tuple[float, float]:
    with emulated_link(LinkSettings(loss=loss, seed=seed), LinkSettings()) as link:
        report = iperf_udp(link, offered_bps=2e6, seconds=5, length=500)
    return loss * 100, lost_percent(report)


def delay_case(delay_ms: float, rate_bps: float) -> tuple[float, float]:
    settings = LinkSettings(rate_bps=rate_bps, delay_ms=delay_ms, queue_bytes=QUEUE)
    with emulated_link(settings, settings) as link:
        delays = one_way_delays_ms(link, count=200)
    return delay_ms + PROBE_BYTES * 8 / rate_bps * 1e3, statistics.median(delays)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    cases = {
        "rate 2.4 Mbps (bps)": lambda run: rate_case(
            LinkSettings(rate_bps=2.4e6, queue_bytes=QUEUE)
        ),
        "rate 500 kbps (bps)": lambda run: rate_case(
            LinkSettings(rate_bps=500e3, queue_bytes=QUEUE)
        ),
        "trace, 1 opportunity / 5 ms (bps)": lambda run: rate_case(
            LinkSettings(trace_ms=list(range(5, 1001, 5)), queue_bytes=QUEUE)
        ),
        "delay 20 ms at 2.4 Mbps (ms)": lambda run: delay_case(20.0, 2.4e6),
        "delay 120 ms at 500 kbps (ms)": lambda run: delay_case(120.0, 500e3),
        "loss 2 % (%)": lambda run: loss_case(0.02, seed=run),
    }
    results = {}
    table = Table("setting", "expected", "measured (median)", "worst error", "runs")
    for name, case in cases.items():
        pairs = [case(run) for run in range(args.runs)]
        expected = pairs[0][0]
        measured = [m for _, m in pairs]
        worst = max(abs(m - expected) for m in measured)
        relative = name.endswith("(bps)")
        worst_text = f"{worst / expected * 100:.2f} %" if relative else f"{worst:.2f}"
        table.add_row(
            name, f"{expected:.4g}", f"{statistics.median(measured):.4g}", worst_text,
            str(args.runs),
        )  # fmt: skip
        results[name] = {"expected": expected, "measured": measured}
    Console().print(table)
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
