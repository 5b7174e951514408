"""The paper's slow link: 500 kbps each way, in network namespaces this test makes and removes.

The teleop server runs in one namespace, a worker's client (its hand tracing a circle, so the
picture changes every frame) in the other, joined by a veth pair
whose both ends are shaped with tc's token bucket (tbf; this kernel has no netem). VP8 starts
below the link rate and follows the receiver's estimate, so no standing queue builds up: the
control-to-photon latency stays near its unshaped value instead of growing toward the
queue's 400 ms limit.
"""

from __future__ import annotations

import json
import os
import secrets
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pytest

from crowdteleop.coord.fleet.launcher import teleop_server_argv
from tests.fixtures import link_client
from tests.fixtures.teleop_process import ADMIN_TOKEN, TOKEN, teleop_config

pytestmark = [
    pytest.mark.slow,
    pytest.mark.exclusive,
]  # runs alone under xdist: frame rate and queueing on a slow link

RATE = "500kbit"


def _sh(*args: str) -> None:
    subprocess.run(args, check=True, capture_output=True)


@pytest.fixture
def shaped_link():
    if os.geteuid() != 0 or not shutil.which("ip") or not shutil.which("tc"):
        pytest.fail("network namespaces need root and iproute2 (ip, tc)", pytrace=False)
    tag = secrets.token_hex(3)
    server_ns, client_ns = f"ct-srv-{tag}", f"ct-cli-{tag}"
    server_if, client_if = f"vs{tag}", f"vc{tag}"
    try:
        _sh("ip", "netns", "add", server_ns)
        _sh("ip", "netns", "add", client_ns)
        _sh("ip", "link", "add", server_if, "type", "veth", "peer", "name", client_if)
        for ns, dev, address in (
            (server_ns, server_if, "10.77.0.1/30"),
            (client_ns, client_if, "10.77.0.2/30"),
        ):
            _sh("ip", "link", "set", dev, "netns", ns)
            _sh("ip", "-n", ns, "addr", "add", address, "dev", dev)
            _sh("ip", "-n", ns, "link", "set", dev, "up")
            _sh("ip", "-n", ns, "link", "set", "lo", "up")
            _sh(
                "tc",
                "-n",
                ns,
                "qdisc",
                "add",
                "dev",
                dev,
                "root",
                "tbf",
                "rate",
                RATE,
                "burst",
                "16kbit",
                "latency",
                "400ms",
            )
        yield server_ns, client_ns
    finally:
        for ns in (server_ns, client_ns):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)


def test_vp8_adapts_to_a_500_kbps_link_without_a_standing_queue(tmp_path, shaped_link):
    server_ns, client_ns = shaped_link
    config_path = tmp_path / "teleop.json"
    config = teleop_config(tmp_path / "episodes")
    config_path.write_text(json.dumps(config))
    server = subprocess.Popen(
        [
            "ip",
            "netns",
            "exec",
            server_ns,
            *teleop_server_argv(config_path, host="10.77.0.1", port=8765),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        ready = server.stdout.readline()
        assert ready.startswith("READY "), ready
        started = time.monotonic()
        client = subprocess.run(
            [
                "ip",
                "netns",
                "exec",
                client_ns,
                sys.executable,
                str(Path(link_client.__file__)),
                "http://10.77.0.1:8765",
                TOKEN,
                ADMIN_TOKEN,
                "--warmup",
                "3",
                "--seconds",
                "20",
            ],
            capture_output=True,
            text=True,
            timeout=180,
        )
        assert client.returncode == 0, client.stderr[-2000:]
        result = json.loads(client.stdout.split("LINK-CLIENT ", 1)[1])
    finally:
        server.terminate()
        server.wait(timeout=30)
    latency = result["latency_ms"]
    half = len(latency) // 2
    early, late = statistics.median(latency[:half]), statistics.median(latency[half:])
    p95 = sorted(latency)[int(0.95 * (len(latency) - 1))]
    print(
        f"500 kbps link: {result['fps']:.1f} fps, latency median {early:.0f} -> {late:.0f} ms"
        f" (first / second half), p95 {p95:.0f} ms"
    )
    assert time.monotonic() - started < 120
    assert result["fps"] > 10, "the picture keeps moving on the slow link"
    # A standing queue would hold each frame up to the shaper's 400 ms limit; an adapting sender
    # stays near the unshaped latency (~60 ms here on a quiet machine, 130-250 ms while other
    # processes load both cores, hence the margin; benchmarks measure, tests tell apart).
    assert late < 350, f"a standing queue: median latency {late:.0f} ms in the second half"
