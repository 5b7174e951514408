"""The database schema (SQLAlchemy 2 ORM). Times are Unix seconds (floats): one meaning on
SQLite and PostgreSQL alike. Changing a table needs a new Alembic revision in migrations/."""

from __future__ import annotations

from typing import Any

from sqlalchemy import (
    JSON,
    Boolean,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column


class Base(DeclarativeBase):
    pass


class Campaign(Base):
    __tablename__ = "campaigns"

    name: Mapped[str] = mapped_column(String(64), primary_key=True)
    config: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[float] = mapped_column(Float)
    updated_at: Mapped[float] = mapped_column(Float)


class Worker(Base):
    __tablename__ = "workers"
    __table_args__ = (UniqueConstraint("source", "external_id", name="uq_workers_external"),)

    id: Mapped[str] = mapped_column(String(40), primary_key=True)
    source: Mapped[str] = mapped_column(String(16))  # prolific | mturk | anonymous
    external_id: Mapped[str | None] = mapped_column(String(128))
    study_id: Mapped[str | None] = mapped_column(String(128))
    external_session: Mapped[str | None] = mapped_column(String(128))
    campaign: Mapped[str] = mapped_column(String(64))
    params: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[float] = mapped_column(Float)
    # The region their last join landed in and the round trips that chose it (a RegionChoice).
    region: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    # Set when an admin blocked the worker: their joins are refused, with the reason kept.
    blocked_at: Mapped[float | None] = mapped_column(Float, default=None)
    blocked_reason: Mapped[str | None] = mapped_column(Text, default=None)


class WorkerToken(Base):
    """Hashes of the bearer tokens a worker was given (one per join; all stay valid)."""

    __tablename__ = "worker_tokens"

    token_hash: Mapped[str] = mapped_column(String(64), primary_key=True)
    worker_id: Mapped[str] = mapped_column(ForeignKey("workers.id", ondelete="CASCADE"), index=True)
    created_at: Mapped[float] = mapped_column(Float)
    # Set when another browser took the worker's live session over: the token then answers
    # 401 "taken_over", so the first browser learns why (coord/guard/identity.py).
    revoked_at: Mapped[float | None] = mapped_column(Float, default=None)


class Session(Base):
    __tablename__ = "sessions"

    id: Mapped[str] = mapped_column(String(40), primary_key=True)
    worker_id: Mapped[str] = mapped_column(ForeignKey("workers.id", ondelete="CASCADE"), index=True)
    campaign: Mapped[str] = mapped_column(String(64), index=True)
    state: Mapped[str] = mapped_column(String(16), index=True)
    task: Mapped[str] = mapped_column(String(64))
    robot: Mapped[str] = mapped_column(String(64))
    controller: Mapped[str] = mapped_column(String(32))
    interfaces: Mapped[list[str]] = mapped_column(JSON)
    time_limit_s: Mapped[float] = mapped_column(Float)
    demos_required: Mapped[int] = mapped_column(Integer)
    demos_done: Mapped[int] = mapped_column(Integer, default=0)
    created_at: Mapped[float] = mapped_column(Float, index=True)  # queue order
    # When it last joined the queue (a session whose server crashed is queued again, at its
    # old place: created_at keeps the order, queued_at times the wait).
    queued_at: Mapped[float | None] = mapped_column(Float, default=None)
    restarts: Mapped[int] = mapped_column(Integer, default=0, server_default="0")
    # HMAC of the client's address key under the server secret: counts live sessions per
    # address without keeping addresses (coord/guard/clients.py, coord/guard/session_keys.py).
    client_tag: Mapped[str | None] = mapped_column(String(64), index=True, default=None)
    admitted_at: Mapped[float | None] = mapped_column(Float)
    ready_at: Mapped[float | None] = mapped_column(Float)
    ended_at: Mapped[float | None] = mapped_column(Float)
    last_heartbeat_at: Mapped[float] = mapped_column(Float)
    ended_reason: Mapped[str | None] = mapped_column(String(16))
    completion_code: Mapped[str | None] = mapped_column(String(32))
    interface: Mapped[str | None] = mapped_column(String(16))  # last one the page reported
    teleop_url: Mapped[str | None] = mapped_column(String(256))
    # The teleop server's tokens are not stored: they are derived from the session id and the
    # coordinator's secret (coord/guard/session_keys.py). The report token is stored hashed.
    report_token_hash: Mapped[str] = mapped_column(String(64), index=True)
    error: Mapped[str | None] = mapped_column(Text)
    # The coordinator replica that launched (or took over) its teleop server and watches it.
    replica: Mapped[str | None] = mapped_column(String(128), index=True, default=None)
    # The worker's region choice when the session began (a RegionChoice): its episodes carry it.
    region: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    # The launcher's name for its server (a Ray actor's): any replica finds it by this, also
    # when the server was born a warm spare under another name.
    server: Mapped[str | None] = mapped_column(String(128), default=None)


class Episode(Base):
    __tablename__ = "episodes"

    episode_id: Mapped[str] = mapped_column(String(64), primary_key=True)
    session_id: Mapped[str] = mapped_column(
        ForeignKey("sessions.id", ondelete="CASCADE"), index=True
    )
    worker_id: Mapped[str] = mapped_column(String(40), index=True)
    number: Mapped[int] = mapped_column(Integer)
    outcome: Mapped[str] = mapped_column(String(32))
    steps: Mapped[int] = mapped_column(Integer)
    duration_s: Mapped[float] = mapped_column(Float)
    uri: Mapped[str] = mapped_column(Text)
    interface: Mapped[str | None] = mapped_column(String(16))
    task: Mapped[str] = mapped_column(String(64))
    telemetry: Mapped[dict[str, Any]] = mapped_column(JSON)
    created_at: Mapped[float] = mapped_column(Float, index=True)
    # its quality metrics as the teleop server measured them (recording/quality.py); null
    # for an episode reported unmeasured. Each number is also a row of `episode_metrics`.
    metrics: Mapped[dict[str, Any] | None] = mapped_column(JSON, default=None)
    # 0-100 against the campaign's successful episodes of the task when it was reported, and
    # the metrics past the campaign's thresholds ([{metric, reason}]).
    score: Mapped[float | None] = mapped_column(Float, index=True, default=None)
    flags: Mapped[list[dict[str, str]] | None] = mapped_column(JSON, default=None)
    # The current review decision (a ReviewDecision; null: undecided or undone) and how many
    # decisions it has had: a reviewer decides against the number they saw, so of two
    # reviewers deciding at once one wins and the other is told (a `review_decisions` row
    # per decision keeps the history).
    decision: Mapped[str | None] = mapped_column(String(16), index=True, default=None)
    review_seq: Mapped[int] = mapped_column(Integer, default=0, server_default="0")


class EpisodeMetric(Base):
    """One quality metric of one episode: indexed by (name, value), so a campaign's
    distribution of a metric per task, and the episodes past a threshold, are one range
    scan, whichever metrics later versions add."""

    __tablename__ = "episode_metrics"
    __table_args__ = (Index("ix_episode_metrics_name_value", "name", "value"),)

    episode_id: Mapped[str] = mapped_column(
        ForeignKey("episodes.episode_id", ondelete="CASCADE"), primary_key=True
    )
    name: Mapped[str] = mapped_column(String(48), primary_key=True)
    value: Mapped[float] = mapped_column(Float)


class ReviewDecisionRow(Base):
    """One decision on one episode, never changed: accept, reject, or undo (decision null),
    by whom (a reviewer's name, or "auto" for the campaign's score rule) and when. `seq` is
    the episode's decision count after it: unique per episode, so two reviewers deciding on
    the same state cannot both be written."""

    __tablename__ = "review_decisions"
    __table_args__ = (UniqueConstraint("episode_id", "seq", name="uq_review_decisions_seq"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    episode_id: Mapped[str] = mapped_column(
        ForeignKey("episodes.episode_id", ondelete="CASCADE"), index=True
    )
    seq: Mapped[int] = mapped_column(Integer)
    decision: Mapped[str | None] = mapped_column(String(16))
    reason: Mapped[str] = mapped_column(Text, default="")
    reviewer: Mapped[str] = mapped_column(String(64))
    automatic: Mapped[bool] = mapped_column(Boolean, default=False)
    at: Mapped[float] = mapped_column(Float, index=True)


class PairingCode(Base):
    __tablename__ = "pairing_codes"

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    code: Mapped[str] = mapped_column(String(16), index=True)
    session_id: Mapped[str] = mapped_column(
        ForeignKey("sessions.id", ondelete="CASCADE"), index=True
    )
    expires_at: Mapped[float] = mapped_column(Float)
    used_at: Mapped[float | None] = mapped_column(Float)
    # The QR code's link also carries a long key: unguessable, so never rate limited.
    key_hash: Mapped[str | None] = mapped_column(String(64), default=None)


class PhoneToken(Base):
    __tablename__ = "phone_tokens"

    token_hash: Mapped[str] = mapped_column(String(64), primary_key=True)
    session_id: Mapped[str] = mapped_column(
        ForeignKey("sessions.id", ondelete="CASCADE"), index=True
    )
    created_at: Mapped[float] = mapped_column(Float)


class Event(Base):
    """An append-only log: joins, admissions, pairings, episodes, endings."""

    __tablename__ = "events"

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    at: Mapped[float] = mapped_column(Float, index=True)
    kind: Mapped[str] = mapped_column(String(32))
    session_id: Mapped[str | None] = mapped_column(String(40), index=True)
    worker_id: Mapped[str | None] = mapped_column(String(40))
    data: Mapped[dict[str, Any]] = mapped_column(JSON)


class Replica(Base):
    """A coordinator serving this database, and when it last said so (coord/db/replicas.py)."""

    __tablename__ = "replicas"

    name: Mapped[str] = mapped_column(String(128), primary_key=True)
    started_at: Mapped[float] = mapped_column(Float)
    seen_at: Mapped[float] = mapped_column(Float)


class Spare(Base):
    """A warm teleop server of some replica (coord/fleet/spares.py): counted by all (on a cluster it
    holds a slot) and claimed by whichever replica admits a worker."""

    __tablename__ = "spares"

    id: Mapped[str] = mapped_column(String(40), primary_key=True)  # its session id (spare-...)
    key: Mapped[str] = mapped_column(String(200), index=True)  # task/robot/controller
    replica: Mapped[str] = mapped_column(String(128), index=True)  # who started and watches it
    server: Mapped[str | None] = mapped_column(String(128))  # the launcher's name for it
    url: Mapped[str | None] = mapped_column(String(256))  # none while it starts
    started_at: Mapped[float] = mapped_column(Float)


class LimitEvent(Base):
    """One counted event of a rate limit every replica shares (wrong pairing codes)."""

    __tablename__ = "limit_events"
    __table_args__ = (Index("ix_limit_events_limiter_key_at", "limiter", "key", "at"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=True)
    limiter: Mapped[str] = mapped_column(String(32))
    key: Mapped[str] = mapped_column(String(128))
    at: Mapped[float] = mapped_column(Float, index=True)
