"""Alembic environment: the coordinator passes an open connection (db.migrate)."""

from __future__ import annotations

from alembic import context

from crowdteleop.coord.db.tables import Base

connection = context.config.attributes.get("connection")
if connection is None:
    raise RuntimeError("run migrations through crowdteleop.coord.db.engine.migrate(url)")

context.configure(
    connection=connection,
    target_metadata=Base.metadata,
    render_as_batch=connection.dialect.name == "sqlite",  # SQLite cannot ALTER most things
    compare_type=True,
)
with context.begin_transaction():
    context.run_migrations()
