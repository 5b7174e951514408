"""episodes' quality metrics

- episodes.metrics: the metrics the teleop server measured as it stored the episode (JSON);
  episodes.score (0-100, indexed) and episodes.flags (JSON) the coordinator gave it.
- episode_metrics: one row per numeric metric, indexed by (name, value), for distributions
  and thresholds.

Revision ID: 0007
Revises: 0006
Create Date: 2026-12-04 22:20:00.000000
"""

from __future__ import annotations

import sqlalchemy as sa
from alembic import op

revision = "0007"
down_revision = "0006"
branch_labels = None
depends_on = None


def upgrade() -> None:
    with op.batch_alter_table("episodes", schema=None) as batch_op:
        batch_op.add_column(sa.Column("metrics", sa.JSON(), nullable=True))
        batch_op.add_column(sa.Column("score", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("flags", sa.JSON(), nullable=True))
        batch_op.create_index(batch_op.f("ix_episodes_score"), ["score"])
    op.create_table(
        "episode_metrics",
        sa.Column("episode_id", sa.String(length=64), nullable=False),
        sa.Column("name", sa.String(length=48), nullable=False),
        sa.Column("value", sa.Float(), nullable=False),
        sa.ForeignKeyConstraint(["episode_id"], ["episodes.episode_id"], ondelete="CASCADE"),
        sa.PrimaryKeyConstraint("episode_id", "name"),
    )
    op.create_index("ix_episode_metrics_name_value", "episode_metrics", ["name", "value"])


def downgrade() -> None:
    op.drop_index("ix_episode_metrics_name_value", table_name="episode_metrics")
    op.drop_table("episode_metrics")
    with op.batch_alter_table("episodes", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_episodes_score"))
        batch_op.drop_column("flags")
        batch_op.drop_column("score")
        batch_op.drop_column("metrics")
