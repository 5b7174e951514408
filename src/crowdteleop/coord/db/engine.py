"""Database URLs, engines and migrations. SQLite (aiosqlite) by default, PostgreSQL (psycopg 3)
by URL; the schema is brought to Alembic's head on every start."""

from __future__ import annotations

import asyncio
from pathlib import Path
from typing import Any

from alembic import command
from alembic.config import Config
from sqlalchemy import CursorResult, Result, create_engine, event
from sqlalchemy.engine import URL, make_url
from sqlalchemy.engine.interfaces import DBAPIConnection
from sqlalchemy.ext.asyncio import (
    AsyncEngine,
    AsyncSession,
    async_sessionmaker,
    create_async_engine,
)
from sqlalchemy.pool import ConnectionPoolEntry

from crowdteleop.coord.guard.private import private_sqlite

MIGRATIONS = Path(__file__).parent / "migrations"


class DatabaseUrlError(ValueError):
    """The URL names a database we do not support."""


def _url(url: str, asynchronous: bool) -> URL:
    parsed = make_url(url)
    backend = parsed.get_backend_name()
    if backend == "sqlite":
        return parsed.set(drivername="sqlite+aiosqlite" if asynchronous else "sqlite")
    if backend in ("postgresql", "postgres"):
        return parsed.set(drivername="postgresql+psycopg")
    raise DatabaseUrlError(f"unsupported database {url!r}: use sqlite:///FILE or postgresql://...")


def sync_url(url: str) -> URL:
    return _url(url, asynchronous=False)


def async_url(url: str) -> URL:
    return _url(url, asynchronous=True)


def _ensure_sqlite_dir(url: URL) -> None:
    """A SQLite file is made 0600 (a new folder for it 0700) before SQLite opens it."""
    if url.get_backend_name() == "sqlite" and url.database and url.database != ":memory:":
        private_sqlite(Path(url.database))


def _sqlite_pragmas(dbapi_connection: DBAPIConnection, _record: ConnectionPoolEntry) -> None:
    cursor = dbapi_connection.cursor()
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute("PRAGMA journal_mode=WAL")  # readers never wait for the writer
    cursor.execute("PRAGMA busy_timeout=5000")
    cursor.close()


def migrate_sync(url: str, revision: str = "head") -> None:
    """Upgrade the schema to `revision` (blocking; call through `migrate`)."""
    target = sync_url(url)
    _ensure_sqlite_dir(target)
    engine = create_engine(target)
    try:
        with engine.begin() as connection:
            config = Config()
            config.set_main_option("script_location", str(MIGRATIONS))
            config.attributes["connection"] = connection
            command.upgrade(config, revision)
        if target.get_backend_name() == "sqlite":
            with engine.connect() as connection:
                # Empty the write-ahead log into the file, and the log itself: what a
                # migration blanked (0002's tokens) must not stay readable in old WAL frames.
                connection.exec_driver_sql("PRAGMA wal_checkpoint(TRUNCATE)")
    finally:
        engine.dispose()


async def migrate(url: str) -> None:
    await asyncio.to_thread(migrate_sync, url)


def make_engine(url: str) -> AsyncEngine:
    target = async_url(url)
    _ensure_sqlite_dir(target)
    engine = create_async_engine(target, pool_pre_ping=True)
    if target.get_backend_name() == "sqlite":
        event.listen(engine.sync_engine, "connect", _sqlite_pragmas)
    return engine


def make_sessionmaker(engine: AsyncEngine) -> async_sessionmaker[AsyncSession]:
    return async_sessionmaker(engine, expire_on_commit=False)


def rowcount(result: Result[*tuple[Any, ...]]) -> int:
    """The rows an UPDATE matched. The ORM runs an UPDATE to a `CursorResult`; SQLAlchemy
    types `AsyncSession.execute` as returning a plain `Result`, which has no row count."""
    assert isinstance(result, CursorResult)
    return result.rowcount
