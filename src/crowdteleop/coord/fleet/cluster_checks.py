"""What a cluster of several machines needs of the coordinator's settings, checked before any
worker is admitted (issue 30): an operator who followed the guide finds out at start, not after
a campaign's demonstrations went uncounted.

- **Reports**: every teleop server posts each stored episode to the coordinator's report
  address. An address on this machine's loopback reaches only servers on this machine.
- **Episodes**: with local storage each server writes episodes to its own node's disk, at the
  coordinator's path. Several machines need S3-compatible storage, or a folder they all mount.
"""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass
from urllib.parse import urlsplit


@dataclass(frozen=True)
class TeleopNode:
    """A live cluster node offering teleop slots, by the address its raylet announced."""

    address: str
    slots: int


class ClusterSetupError(RuntimeError):
    """The cluster cannot serve a campaign with these settings; the message says what to set."""


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def report_problem(nodes: list[TeleopNode], report_url: str, here: set[str]) -> str | None:
    """Why servers on some node could not reach `report_url` (a loopback address while the
    node is another machine), or None."""
    host = urlsplit(report_url).hostname or ""
    if not is_loopback(host):
        return None
    away = sorted({n.address for n in nodes if not (n.address in here or is_loopback(n.address))})
    if not away:
        return None
    return (
        f"teleop servers on {', '.join(away)} would report episodes to {report_url}, this "
        "machine's loopback, which they cannot reach: their workers' demonstrations would never "
        "count. Set `internal_url` to an address every node reaches (the public URL through "
        "the reverse proxy, or this machine's address on the cluster's network; docs/deploy.md, "
        "'A Ray cluster')"
    )


def storage_problem(nodes: list[TeleopNode], episodes_shared: bool) -> str | None:
    """Why episodes would be scattered over the nodes' own disks, or None."""
    machines = sorted({n.address for n in nodes})
    if episodes_shared or len(machines) < 2:
        return None
    return (
        f"teleop servers on {len(machines)} machines ({', '.join(machines)}) would each keep "
        "their episodes on their own disk, where the coordinator and `dataset build` do not "
        "see them. Use S3-compatible storage (`teleop.recording.storage`, docs/deploy.md) or, "
        "if `data_dir` is on storage every node mounts at the same path, say so with "
        "`ray: {shared_storage: true}`"
    )


def cluster_problems(
    nodes: list[TeleopNode], report_url: str, episodes_shared: bool, here: set[str]
) -> list[str]:
    """Everything that keeps this cluster from serving the campaign; empty when it can."""
    found = [report_problem(nodes, report_url, here), storage_problem(nodes, episodes_shared)]
    return [problem for problem in found if problem is not None]
