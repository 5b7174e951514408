"""What the coordinator counts, for `/metrics` (Prometheus's text format) and the admin page.

One registry per app (never prometheus_client's global one), so two apps in one process (the
tests) count apart. Counters count events since this process started; gauges are read from the
database when scraped.
"""

from __future__ import annotations

from typing import Literal, get_args

from prometheus_client import CollectorRegistry, Counter, Gauge, generate_latest

# Why a request was refused: one vocabulary for the metrics, the admin page and the docs.
Refusal = Literal[
    "join_rate_address",  # joins from one address past joins_per_minute_per_address
    "join_rate_total",  # joins from everyone past joins_per_minute
    "anonymous",  # a campaign that takes study links only
    "queue_full",  # max_queue sessions already waiting
    "wait_too_long",  # the estimated wait is past max_wait_s
    "sessions_per_address",  # live sessions from one address past live_sessions_per_address
    "in_use",  # another browser holds the worker's live session
    "blocked",  # a worker an admin blocked joined or asked for a session
    "unknown_region",  # a join's round trips name a region its campaign does not list
    "pair_bad_code",  # a wrong, used or expired pairing code
    "pair_rate_address",  # wrong codes from one address past pair_failures_per_minute
    "pair_rate_total",  # wrong codes from everyone past pair_failures_per_minute_total
    "admin_bad_token",  # a wrong admin token
    "admin_rate",  # wrong admin tokens from one address past admin_failures_per_minute
    "review_unknown_episode",  # a decision or a look at an episode that does not exist
    "review_conflict",  # a decision on an episode decided meanwhile (or nothing to undo)
    "review_invalid",  # a malformed filter or decision on the review API
]
RestartCause = Literal["exited", "hung", "coordinator_restart"]


class CoordMetrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        self.joins = Counter(
            "crowdteleop_joins", "Joins accepted", ["source"], registry=self.registry
        )
        self.refusals = Counter(
            "crowdteleop_refusals",
            "Requests refused by a limit",
            ["reason"],
            registry=self.registry,
        )
        self.restarts = Counter(
            "crowdteleop_session_restarts",
            "Sessions given a new teleop server (theirs exited or hung, or we restarted)",
            ["cause"],
            registry=self.registry,
        )
        self.ended = Counter(
            "crowdteleop_sessions_ended", "Sessions ended", ["reason"], registry=self.registry
        )
        self.episodes = Counter(
            "crowdteleop_episodes", "Episodes reported", ["outcome"], registry=self.registry
        )
        self.blocks = Counter(
            "crowdteleop_workers_blocked",
            "Workers blocked by an admin (unblocks not subtracted)",
            registry=self.registry,
        )
        self.launch_failures = Counter(
            "crowdteleop_launch_failures",
            "Teleop servers that did not start",
            registry=self.registry,
        )
        self.sessions = Gauge(
            "crowdteleop_sessions", "Live sessions by state", ["state"], registry=self.registry
        )
        self.capacity = Gauge(
            "crowdteleop_capacity", "Teleop servers allowed at once", registry=self.registry
        )
        self.spares = Gauge(
            "crowdteleop_spare_servers", "Warm spare teleop servers ready", registry=self.registry
        )
        self.demos_last_hour = Gauge(
            "crowdteleop_demos_last_hour",
            "Successful demonstrations reported in the last hour",
            registry=self.registry,
        )
        self.spool_pending = Gauge(
            "crowdteleop_spool_pending",
            "Episodes in the teleop servers' spools waiting for the object store (last probe)",
            registry=self.registry,
        )
        self.reports_pending = Gauge(
            "crowdteleop_reports_pending",
            "Stored episodes the teleop servers could not yet report here (last probe): "
            "their demonstrations are not counted until they are",
            registry=self.registry,
        )
        self.servers_unable_to_report = Gauge(
            "crowdteleop_servers_unable_to_report",
            "Teleop servers that cannot reach this coordinator at their report address "
            "(internal_url, docs/deploy.md)",
            registry=self.registry,
        )

    def refused(self, reason: Refusal) -> None:
        self.refusals.labels(reason=reason).inc()

    def refusal_counts(self) -> dict[str, int]:
        """Refusals so far by reason (every reason listed, zeros included), for the admin page."""
        return _by_label(self.refusals, "reason", get_args(Refusal))

    def restarts_by_cause(self) -> dict[str, int]:
        return _by_label(self.restarts, "cause", get_args(RestartCause))

    def exposition(self) -> bytes:
        return generate_latest(self.registry)


def _by_label(counter: Counter, label: str, names: tuple[str, ...]) -> dict[str, int]:
    """A labelled counter's totals by `label`, every name in `names` listed."""
    counts = dict.fromkeys(names, 0)
    for metric in counter.collect():
        for sample in metric.samples:
            if sample.name.endswith("_total"):
                counts[sample.labels[label]] = int(sample.value)
    return counts
