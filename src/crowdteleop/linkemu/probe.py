"""One-way delay by timestamps (`python -m crowdteleop.linkemu.probe`):
`send HOST PORT COUNT INTERVAL_S` stamps each datagram with the sender's clock;
`receive HOST PORT COUNT` prints, as JSON, arrival minus stamp for each. Both ends run on one
machine (in two namespaces), so they read the same clock."""

from __future__ import annotations

import json
import socket
import struct
import sys
import time


def send(host: str, port: int, count: int, interval_s: float) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for number in range(count):
            sock.sendto(struct.pack("!Iq", number, time.monotonic_ns()) + bytes(100), (host, port))
            time.sleep(interval_s)


def receive(host: str, port: int, count: int) -> None:
    delays_ms: list[float] = []
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind((host, port))
        sock.settimeout(10)
        print("listening", flush=True)
        try:
            while len(delays_ms) < count:
                data = sock.recv(2048)
                _number, sent_ns = struct.unpack("!Iq", data[:12])
                delays_ms.append((time.monotonic_ns() - sent_ns) / 1e6)
        except TimeoutError:
            pass
    print(json.dumps(delays_ms), flush=True)


if __name__ == "__main__":
    mode, host, port, count = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    if mode == "send":
        send(host, port, count, float(sys.argv[5]))
    else:
        receive(host, port, count)
