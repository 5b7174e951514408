"""The emulator's process: reads every IP packet one namespace's TUN device emits, lets the
link decide its fate (`shaping.Direction`), and writes it into the other's at its time.

Run by `linkemu.netns.emulated_link`; standalone:
`python -m crowdteleop.linkemu.forwarder NS_A NS_B --up JSON --down JSON [--stats FILE]`,
where JSON is a `LinkSettings` (up: A to B). Prints `ready` once both devices are up.
SIGUSR1 cuts the link both ways (every packet lost, as a pulled cable), SIGUSR2 restores it.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
from collections import deque
from dataclasses import asdict
from pathlib import Path

from crowdteleop.linkemu.shaping import Direction, LinkSettings
from crowdteleop.linkemu.tun import address, open_tun

DEVICE = "emu0"
ADDRESS_A, ADDRESS_B = "10.79.0.1", "10.79.0.2"
MAX_PACKET = 65535


class Pipe:
    """One direction: packets from `source` into `sink` when the link says."""

    def __init__(self, source: int, sink: int, settings: LinkSettings) -> None:
        self.source, self.sink = source, sink
        self.link = Direction(settings)
        self.loop = asyncio.get_running_loop()
        self.start_s = self.loop.time()
        self.pending: deque[tuple[float, bytes]] = deque()
        self.timer: asyncio.TimerHandle | None = None
        self.write_errors = 0
        self.late_ms_max = 0.0  # how far behind its time the latest packet left (loop lag)

    def readable(self) -> None:
        while True:
            try:
                packet = os.read(self.source, MAX_PACKET)
            except BlockingIOError:
                return
            now = self.loop.time()
            due = self.link.push(len(packet), now - self.start_s)
            if due is None:
                continue
            self.pending.append((self.start_s + due, packet))
            if self.timer is None:
                self.flush()

    def flush(self) -> None:
        self.timer = None
        now = self.loop.time()
        while self.pending and self.pending[0][0] <= now:
            due, packet = self.pending.popleft()
            self.late_ms_max = max(self.late_ms_max, (now - due) * 1e3)
            try:
                os.write(self.sink, packet)
            except OSError:
                self.write_errors += 1
        if self.pending:
            self.timer = self.loop.call_at(self.pending[0][0], self.flush)

    def stats(self) -> dict[str, float | int]:
        return {
            **asdict(self.link.counters),
            "write_errors": self.write_errors,
            "late_ms_max": round(self.late_ms_max, 3),
        }


async def forward(
    ns_a: str, ns_b: str, up: LinkSettings, down: LinkSettings, stats: Path | None
) -> None:
    fd_a, fd_b = open_tun(ns_a, DEVICE), open_tun(ns_b, DEVICE)
    address(ns_a, DEVICE, ADDRESS_A, ADDRESS_B)
    address(ns_b, DEVICE, ADDRESS_B, ADDRESS_A)
    loop = asyncio.get_running_loop()
    pipes = {"up": Pipe(fd_a, fd_b, up), "down": Pipe(fd_b, fd_a, down)}
    loop.add_reader(fd_a, pipes["up"].readable)
    loop.add_reader(fd_b, pipes["down"].readable)
    stop = asyncio.Event()
    for signum in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(signum, stop.set)

    def cut(is_cut: bool) -> None:
        for pipe in pipes.values():
            pipe.link.is_cut = is_cut

    loop.add_signal_handler(signal.SIGUSR1, cut, True)
    loop.add_signal_handler(signal.SIGUSR2, cut, False)
    print("ready", flush=True)
    while not stop.is_set():
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(stop.wait(), 1.0)
        if stats is not None:  # written each second, so a killed forwarder still leaves some
            stats.write_text(json.dumps({name: pipe.stats() for name, pipe in pipes.items()}))
    os.close(fd_a)
    os.close(fd_b)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("ns_a")
    parser.add_argument("ns_b")
    parser.add_argument("--up", default="{}", help="LinkSettings JSON, A to B")
    parser.add_argument("--down", default="{}", help="LinkSettings JSON, B to A")
    parser.add_argument("--stats", type=Path, default=None)
    args = parser.parse_args()
    if os.geteuid() == 0:
        # Ahead of busy neighbours (but not real-time): a late packet is a wrong delay.
        os.nice(-10)
    up = LinkSettings.model_validate_json(args.up)
    down = LinkSettings.model_validate_json(args.down)
    asyncio.run(forward(args.ns_a, args.ns_b, up, down, args.stats))


if __name__ == "__main__":
    main()
