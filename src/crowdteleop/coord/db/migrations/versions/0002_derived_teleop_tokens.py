"""teleop tokens derived, not stored

The sessions' teleop tokens are HMACs of the session id under the coordinator's secret
(coord/guard/session_keys.py), so their columns go. The values are blanked first, with SQLite's
secure_delete on, so the old tokens do not linger in the file's free pages.

Revision ID: 0002
Revises: 0001
Create Date: 2026-12-02 10:00:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None

COLUMNS = ("teleop_token", "teleop_admin_token")


def upgrade() -> None:
    if op.get_bind().dialect.name == "sqlite":
        op.execute("PRAGMA secure_delete = ON")  # freed space is overwritten with zeros
    op.execute("UPDATE sessions SET teleop_token = '', teleop_admin_token = ''")
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        for column in COLUMNS:
            batch_op.drop_column(column)


def downgrade() -> None:
    # The tokens of old sessions cannot come back (they were never stored after 0002); the
    # coordinator ends every session a previous run left, so none is needed.
    with op.batch_alter_table("sessions", schema=None) as batch_op:
        for column in COLUMNS:
            batch_op.add_column(
                sa.Column(column, sa.String(length=128), nullable=False, server_default="")
            )
