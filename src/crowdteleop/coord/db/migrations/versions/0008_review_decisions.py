"""review decisions and blocked workers

- review_decisions: every accept / reject / undo of an episode, with who and when, never
  changed; unique (episode_id, seq) so two reviewers deciding at once cannot both land.
- episodes.decision (indexed) and episodes.review_seq: the current decision and its number.
- workers.blocked_at / blocked_reason: a blocked worker's joins are refused.

Revision ID: 0008
Revises: 0007
Create Date: 2026-12-05 01:00:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0008"
down_revision = "0007"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("episodes", schema=None) as batch_op:
        batch_op.add_column(sa.Column("decision", sa.String(length=16), nullable=True))
        batch_op.add_column(
            sa.Column("review_seq", sa.Integer(), nullable=False, server_default="0")
        )
        batch_op.create_index(batch_op.f("ix_episodes_decision"), ["decision"])
    with op.batch_alter_table("workers", schema=None) as batch_op:
        batch_op.add_column(sa.Column("blocked_at", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("blocked_reason", sa.Text(), nullable=True))
    op.create_table(
        "review_decisions",
        sa.Column("id", sa.Integer(), autoincrement=True, nullable=False),
        sa.Column("episode_id", sa.String(length=64), nullable=False),
        sa.Column("seq", sa.Integer(), nullable=False),
        sa.Column("decision", sa.String(length=16), nullable=True),
        sa.Column("reason", sa.Text(), nullable=False),
        sa.Column("reviewer", sa.String(length=64), nullable=False),
        sa.Column("automatic", sa.Boolean(), nullable=False),
        sa.Column("at", sa.Float(), nullable=False),
        sa.ForeignKeyConstraint(["episode_id"], ["episodes.episode_id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("id"),
        sa.UniqueConstraint("episode_id", "seq", name="uq_review_decisions_seq"),
    )
    op.create_index("ix_review_decisions_episode_id", "review_decisions", ["episode_id"])
    op.create_index("ix_review_decisions_at", "review_decisions", ["at"])


def downgrade() -> None:
    op.drop_index("ix_review_decisions_at", table_name="review_decisions")
    op.drop_index("ix_review_decisions_episode_id", table_name="review_decisions")
    op.drop_table("review_decisions")
    with op.batch_alter_table("workers", schema=None) as batch_op:
        batch_op.drop_column("blocked_reason")
        batch_op.drop_column("blocked_at")
    with op.batch_alter_table("episodes", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_episodes_decision"))
        batch_op.drop_column("review_seq")
        batch_op.drop_column("decision")
