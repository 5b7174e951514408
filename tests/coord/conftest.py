"""The coordination server's databases for its tests: SQLite and the machine's real
PostgreSQL."""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from pathlib import Path

import pytest

POSTGRES_ADMIN_URL = os.environ.get(
    "CROWDTELEOP_TEST_POSTGRES", "postgresql://postgres@127.0.0.1:5432/test"
)


@pytest.fixture(scope="session")
def postgres_database() -> Iterator[str]:
    """A database of its own on the machine's PostgreSQL for this test run, dropped after."""
    import psycopg

    name = f"crowdteleop_test_{secrets.token_hex(4)}"
    try:
        admin = psycopg.connect(POSTGRES_ADMIN_URL, autocommit=True, connect_timeout=5)
    except psycopg.OperationalError as exc:
        pytest.fail(
            f"PostgreSQL is not reachable at {POSTGRES_ADMIN_URL} ({exc}). The database tests "
            "run against a real PostgreSQL: `bash scripts/system-deps.sh test` installs and "
            "starts it (or set CROWDTELEOP_TEST_POSTGRES to another server's URL).",
            pytrace=False,
        )
    with admin:
        admin.execute(f'CREATE DATABASE "{name}"')
    base = POSTGRES_ADMIN_URL.rsplit("/", 1)[0]
    try:
        yield f"{base}/{name}"
    finally:
        with psycopg.connect(POSTGRES_ADMIN_URL, autocommit=True) as admin:
            admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


@pytest.fixture(params=["sqlite", "postgresql"])
def database_url(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[str]:
    """An empty database of each kind; on PostgreSQL, a fresh schema-less database per test."""
    if request.param == "sqlite":
        yield f"sqlite:///{tmp_path / 'coord.sqlite3'}"
        return
    import psycopg

    server = request.getfixturevalue("postgres_database")
    with psycopg.connect(server, autocommit=True) as db:
        db.execute("DROP SCHEMA public CASCADE")
        db.execute("CREATE SCHEMA public")
    yield server


@pytest.fixture
def shared_database(postgres_database: str) -> str:
    """The session's PostgreSQL database, emptied: what several replicas of a test share."""
    import psycopg

    with psycopg.connect(postgres_database, autocommit=True) as db:
        db.execute("DROP SCHEMA public CASCADE")
        db.execute("CREATE SCHEMA public")
    return postgres_database
