"""warm spares every replica counts and claims

- spares: each replica's warm teleop servers (on a cluster they hold slots; any replica may
  hand one to a worker).
- sessions.server: the launcher's name for the session's server, so a replica taking the
  session over finds it even when it was born a spare under another name.

Revision ID: 0006
Revises: 0005
Create Date: 2026-12-03 07:30:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0006"
down_revision = "0005"
branch_labels = None
depends_on = None


def upgrade() -> None:
    op.create_table(
        "spares",
        sa.Column("id", sa.String(length=40), nullable=False),
        sa.Column("key", sa.String(length=200), nullable=False),
        sa.Column("replica", sa.String(length=128), nullable=False),
        sa.Column("server", sa.String(length=128), nullable=True),
        sa.Column("url", sa.String(length=256), nullable=True),
        sa.Column("started_at", sa.Float(), nullable=False),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index(op.f("ix_spares_key"), "spares", ["key"])
    op.create_index(op.f("ix_spares_replica"), "spares", ["replica"])
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        batch_op.add_column(sa.Column("server", sa.String(length=128), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        batch_op.drop_column("server")
    op.drop_index(op.f("ix_spares_replica"), table_name="spares")
    op.drop_index(op.f("ix_spares_key"), table_name="spares")
    op.drop_table("spares")
