"""regions: where each worker was sent, and why

- workers.region: the region their last join landed in, with the round trips measured.
- sessions.region: the same, as of the session's start (its episodes carry it).

Revision ID: 0005
Revises: 0004
Create Date: 2026-12-03 07:00:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0005"
down_revision = "0004"
branch_labels = None
depends_on = None


def upgrade() -> None:
    for table in ("workers", "sessions"):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.add_column(sa.Column("region", sa.JSON(), nullable=True))


def downgrade() -> None:
    for table in ("sessions", "workers"):
        with op.batch_alter_table(table, schema=None) as batch_op:
            batch_op.drop_column("region")
