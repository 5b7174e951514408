"""Two network namespaces joined by an emulated link: made, used, removed.

    with emulated_link(up=LinkSettings(rate_bps=2.4e6, delay_ms=20), down=...) as link:
        subprocess.run(link.run_in("a", ["iperf3", "-c", link.address_b, ...]))

Needs root (namespaces, TUN devices). Nothing outside the two namespaces is touched: they
have no route anywhere but to each other.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import signal
import subprocess
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from crowdteleop.linkemu.forwarder import ADDRESS_A, ADDRESS_B
from crowdteleop.linkemu.shaping import LinkSettings

Side = Literal["a", "b"]


class LinkUnavailableError(RuntimeError):
    """This machine cannot make the link (not root, no /dev/net/tun, no `ip`)."""


@dataclass
class EmulatedLink:
    namespace_a: str
    namespace_b: str
    address_a: str
    address_b: str
    stats_path: Path
    forwarder_pid: int

    def cut(self) -> None:
        """Every packet lost both ways from now on, as a pulled cable, until `restore`."""
        os.kill(self.forwarder_pid, signal.SIGUSR1)

    def restore(self) -> None:
        os.kill(self.forwarder_pid, signal.SIGUSR2)

    def namespace(self, side: Side) -> str:
        return self.namespace_a if side == "a" else self.namespace_b

    def run_in(self, side: Side, command: Sequence[str]) -> list[str]:
        """`command` as run inside one side's namespace."""
        return ["ip", "netns", "exec", self.namespace(side), *command]

    def stats(self) -> dict[str, Any]:
        """The forwarder's counters per direction (up: A to B), as of its last second."""
        with contextlib.suppress(FileNotFoundError, json.JSONDecodeError):
            stats: dict[str, Any] = json.loads(self.stats_path.read_text())
            return stats
        return {}


def check_available() -> None:
    if os.geteuid() != 0:
        raise LinkUnavailableError("an emulated link needs root (namespaces and TUN devices)")
    if not os.path.exists("/dev/net/tun"):
        raise LinkUnavailableError("no /dev/net/tun on this machine")


@contextlib.contextmanager
def emulated_link(
    up: LinkSettings, down: LinkSettings, workdir: Path | None = None
) -> Iterator[EmulatedLink]:
    """Namespaces `ctemu-a-*` and `ctemu-b-*`, the forwarder between them; all removed after."""
    check_available()
    tag = secrets.token_hex(3)
    names = (f"ctemu-a-{tag}", f"ctemu-b-{tag}")
    folder = workdir or Path(f"/tmp/ctemu-{tag}")
    folder.mkdir(parents=True, exist_ok=True)
    stats = folder / "link-stats.json"
    forwarder: subprocess.Popen[str] | None = None
    made: list[str] = []
    try:
        for name in names:
            subprocess.run(["ip", "netns", "add", name], check=True, capture_output=True)
            made.append(name)
        command = [sys.executable, "-m", "crowdteleop.linkemu.forwarder", *names]
        command += ["--up", up.model_dump_json(), "--down", down.model_dump_json()]
        command += ["--stats", str(stats)]
        forwarder = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        assert forwarder.stdout is not None and forwarder.stderr is not None
        if forwarder.stdout.readline().strip() != "ready":
            forwarder.wait(10)
            raise LinkUnavailableError(f"the forwarder did not start: {forwarder.stderr.read()}")
        yield EmulatedLink(names[0], names[1], ADDRESS_A, ADDRESS_B, stats, forwarder.pid)
    finally:
        if forwarder is not None:
            forwarder.terminate()
            try:
                forwarder.wait(10)
            except subprocess.TimeoutExpired:
                forwarder.kill()
                forwarder.wait()
        for name in made:
            subprocess.run(["ip", "netns", "del", name], capture_output=True)
