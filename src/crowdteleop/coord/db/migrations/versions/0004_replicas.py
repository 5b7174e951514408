"""coordinator replicas sharing one database

- replicas: each coordinator serving the database, with the time it last said so.
- sessions.replica: the replica watching the session's teleop server.
- limit_events: the wrong pairing codes every replica counts together.

Revision ID: 0004
Revises: 0003
Create Date: 2026-12-03 04:00:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0004"
down_revision = "0003"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "replicas",
        sa.Column("name", sa.String(length=128), nullable=False),
        sa.Column("started_at", sa.Float(), nullable=False),
        sa.Column("seen_at", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint("name"),
    )
    op.create_table(
        "limit_events",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("limiter", sa.String(length=32), nullable=False),
        sa.Column("key", sa.String(length=128), nullable=False),
        sa.Column("at", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index("ix_limit_events_limiter_key_at", "limit_events", ["limiter", "key", "at"])
    op.create_index(op.f("ix_limit_events_at"), "limit_events", ["at"])
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        batch_op.add_column(sa.Column("replica", sa.String(length=128), nullable=True))
        batch_op.create_index(batch_op.f("ix_sessions_replica"), ["replica"], unique=False)


def downgrade() -> None:
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_sessions_replica"))
        batch_op.drop_column("replica")
    op.drop_index(op.f("ix_limit_events_at"), table_name="limit_events")
    op.drop_index("ix_limit_events_limiter_key_at", table_name="limit_events")
    op.drop_table("limit_events")
    op.drop_table("replicas")
