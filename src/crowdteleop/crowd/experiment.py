"""The paper's network experiment (Sec. 4.3, Tables 4-6) with bots: for each link condition, a
coordinator and its teleop servers in one namespace, a crowd of bots in the other, the
emulated link (`linkemu`) between them, both ways. Each condition's episodes are recorded
with the condition's name as `network_condition`, so `crowdteleop dataset stats` groups them
and gives the KS table across conditions.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from crowdteleop.linkemu.netns import EmulatedLink, emulated_link
from crowdteleop.linkemu.shaping import LinkSettings
from crowdteleop.teleop.ready import stop_gracefully, wait_ready

QUEUE_BYTES = 64_000  # ~210 ms at 2.4 Mbps, ~1 s at 500 kbps: a cellular link's deep buffer
COORD_PORT = 8000


@dataclass(frozen=True)
class Condition:
    name: str
    rate_bps: float | None = None
    delay_ms: float = 0.0
    loss: float = 0.0
    trace_ms: tuple[int, ...] | None = None

    def link(self, seed: int, workers: int = 1) -> LinkSettings:
        """The link `workers` bots share, each with this condition's capacity and queue as
        its fair share (the paper gave every worker a link of their own)."""
        trace = [t for t in self.trace_ms for _ in range(workers)] if self.trace_ms else None
        return LinkSettings(
            rate_bps=None if trace or self.rate_bps is None else self.rate_bps * workers,
            trace_ms=trace,
            delay_ms=self.delay_ms,
            queue_bytes=QUEUE_BYTES * workers,
            loss=self.loss,
            seed=seed,
        )


PAPER_CONDITIONS = (
    Condition("baseline", rate_bps=2.4e6, delay_ms=20),
    Condition("low-capacity", rate_bps=500e3, delay_ms=20),
    Condition("high-delay", rate_bps=2.4e6, delay_ms=120),
    Condition("both", rate_bps=500e3, delay_ms=120),
    Condition("lossy", rate_bps=2.4e6, delay_ms=20, loss=0.02),
)


@dataclass
class ConditionRun:
    condition: str
    task: str
    episodes_dir: Path
    crowd: dict[str, Any] = field(default_factory=dict)  # the bots' JSON report
    link: dict[str, Any] = field(default_factory=dict)  # the forwarder's counters
    seconds: float = 0.0


def coordinator_config(label: str, task: str, bots: int, demos: int) -> dict[str, Any]:
    """One campaign `network` of `task`, a slot per bot, every episode labelled."""
    return {
        "capacity": bots,
        "spare_servers": 0,
        "admission": {"live_sessions_per_address": 256, "joins_per_minute_per_address": 600},
        "teleop": {"recording": {"labels": {"network_condition": label}}},
        "campaigns": [
            {"name": "network", "tasks": [task], "demos_required": demos, "time_limit_s": 3600}
        ],
    }


@contextlib.contextmanager
def platform_over_link(
    up: LinkSettings,
    down: LinkSettings,
    config: dict[str, Any],
    folder: Path,
    admin_token: str,
) -> Iterator[tuple[EmulatedLink, str]]:
    """A coordinator (with `config`, its teleop servers listening on the link's address) in
    namespace B behind an emulated link; yields the link and the URL bots in A join at."""
    with emulated_link(up, down) as link:
        config = {**config, "teleop_host": link.address_b}
        (folder / "coord.json").write_text(json.dumps(config))
        log = folder / "coord.log"
        serve = [sys.executable, "-m", "crowdteleop", "serve", "--host", link.address_b]
        serve += ["--port", str(COORD_PORT), "--admin-token", admin_token]
        serve += ["--data-dir", str(folder / "data"), "--config", str(folder / "coord.json")]
        with log.open("w") as log_file:
            coordinator = subprocess.Popen(
                link.run_in("b", serve), stdout=subprocess.PIPE, stderr=log_file, text=True
            )
        try:
            yield link, wait_ready(coordinator, log, 90.0, "the coordinator")
        finally:
            stop_gracefully(coordinator, 60)


def crowd_command(
    url: str, bots: int, task: str, admin_token: str, timeout_s: float, report: Path
) -> list[str]:
    """`crowdteleop bot --coordinator ...` for `bots` bots of the `network` campaign."""
    crowd = [sys.executable, "-m", "crowdteleop", "bot", "--coordinator", url]
    crowd += ["--count", str(bots), "--admin-token", admin_token]
    crowd += ["--campaign", "network", "--task", task, "--timeout", str(timeout_s)]
    return [*crowd, "--json", str(report)]


def run_condition(
    condition: Condition,
    task: str,
    bots: int,
    demos_per_bot: int,
    workdir: Path,
    admin_token: str,
    timeout_s: float = 1800.0,
    seed: int = 0,
) -> ConditionRun:
    """Run one condition to the end; needs root (namespaces). Episodes stay in `workdir`."""
    folder = workdir / f"{task}-{condition.name}"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    started = time.monotonic()
    settings = condition.link(seed, bots)
    config = coordinator_config(condition.name, task, bots, demos_per_bot)
    down = settings.model_copy(update={"seed": seed + 1})
    with platform_over_link(settings, down, config, folder, admin_token) as (link, url):
        report = folder / "crowd.json"
        with (folder / "crowd.log").open("w") as crowd_log:
            subprocess.run(
                link.run_in("a", crowd_command(url, bots, task, admin_token, timeout_s, report)),
                stdout=crowd_log,
                stderr=subprocess.STDOUT,
                timeout=timeout_s + 300,
            )
        run = ConditionRun(condition.name, task, folder / "data" / "episodes")
        run.crowd = json.loads(report.read_text()) if report.exists() else {}
        run.link = link.stats()
    run.seconds = time.monotonic() - started
    return run
