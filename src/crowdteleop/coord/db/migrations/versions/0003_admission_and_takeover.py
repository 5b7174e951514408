"""admission limits, restarts that keep a worker's place, take-over, pairing keys

- sessions.queued_at, sessions.restarts: a session whose teleop server crashed or hung is
  queued again at its old place (created_at) with its count kept, a bounded number of times.
- sessions.client_tag: an HMAC of the client's address, to cap live sessions per address.
- worker_tokens.revoked_at: a token whose live session another browser took over.
- pairing_codes.key_hash: the QR link's long key, which needs no rate limit.

Revision ID: 0003
Revises: 0002
Create Date: 2026-12-02 12:00:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0003"
down_revision = "0002"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        batch_op.add_column(sa.Column("queued_at", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("restarts", sa.Integer(), nullable=False, server_default="0"))
        batch_op.add_column(sa.Column("client_tag", sa.String(length=64), nullable=True))
        batch_op.create_index(batch_op.f("ix_sessions_client_tag"), ["client_tag"], unique=False)
    with op.batch_alter_table("worker_tokens", schema=None) as batch_op:
        batch_op.add_column(sa.Column("revoked_at", sa.Float(), nullable=True))
    with op.batch_alter_table("pairing_codes", schema=None) as batch_op:
        batch_op.add_column(sa.Column("key_hash", sa.String(length=64), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("pairing_codes", schema=None) as batch_op:
        batch_op.drop_column("key_hash")
    with op.batch_alter_table("worker_tokens", schema=None) as batch_op:
        batch_op.drop_column("revoked_at")
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_sessions_client_tag"))
        batch_op.drop_column("client_tag")
        batch_op.drop_column("restarts")
        batch_op.drop_column("queued_at")
