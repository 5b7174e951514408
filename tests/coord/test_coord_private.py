"""Secrets at rest: the coordinator's folders are 0700 and its database and every file holding
a token 0600 from the start; what an earlier run left looser is tightened, and says so."""

from __future__ import annotations

import logging
import os
import sqlite3
import stat
from pathlib import Path

import pytest

from crowdteleop.coord.db.engine import migrate_sync
from crowdteleop.coord.guard.private import write_private
from tests.fixtures.coord import OFFER_SDP, Api, FakeLauncher, coord_config, in_process_app

pytestmark = pytest.mark.filterwarnings("ignore:Using `httpx`")


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def database_bytes(database: Path) -> bytes:
    """The database file and its write-ahead log, as a thief copying them would have them."""
    return b"".join(
        p.read_bytes() for p in (database, database.with_name(database.name + "-wal")) if p.exists()
    )


def test_the_data_folder_and_database_are_private_right_after_start(tmp_path):
    data = tmp_path / "data"
    database = data / "coord.sqlite3"  # where `crowdteleop serve` puts it
    launcher = FakeLauncher()
    config = coord_config(tmp_path, database_url=f"sqlite:///{database}")
    with in_process_app(config, launcher) as client:
        api = Api(client)
        worker = api.join()
        api.new_session(worker["worker_token"])  # writes: the -wal and -shm exist now
        modes = {
            "data": mode(data),
            "sessions": mode(data / "sessions"),
            "state": mode(data / "state"),
            "secret": mode(data / "state" / "session.key"),
            "database": mode(database),
            "wal": mode(database.with_name("coord.sqlite3-wal")),
            "shm": mode(database.with_name("coord.sqlite3-shm")),
        }
    assert modes == {
        "data": 0o700,
        "sessions": 0o700,
        "state": 0o700,
        "secret": 0o600,
        "database": 0o600,
        "wal": 0o600,
        "shm": 0o600,
    }


def test_no_token_is_in_the_database_file_in_plain_text(tmp_path):
    database = tmp_path / "data" / "coord.sqlite3"
    launcher = FakeLauncher()
    config = coord_config(tmp_path, database_url=f"sqlite:///{database}")
    with in_process_app(config, launcher) as client:
        api = Api(client)
        worker = api.join()
        sid = api.new_session(worker["worker_token"])["session_id"]
        api.wait_state(worker["worker_token"], sid, "ready")
        access = api.admin(f"sessions/{sid}/teleop")
        teleop = launcher.handles[sid].config
        offer = client.post(
            f"/api/sessions/{sid}/offer",
            headers=api.auth(worker["worker_token"]),
            json={"sdp": OFFER_SDP, "type": "offer"},
        )
        stored = database_bytes(database)
    assert offer.status_code == 200, "the coordinator still presents the session's token"
    assert launcher.handles[sid].offers[0]["token"] == teleop.token == access["token"]
    assert access["admin_token"] == teleop.admin_token
    assert sid.encode() in stored, "the file is the one the coordinator writes"
    secrets = {
        "teleop token": teleop.token,
        "teleop admin token": teleop.admin_token,
        "report token": teleop.report_token,
        "worker token": worker["worker_token"],
    }
    for name, secret in secrets.items():
        assert secret and secret.encode() not in stored, f"the {name} is in the database file"


def test_what_an_earlier_run_left_readable_is_tightened_and_logged(tmp_path, caplog):
    data = tmp_path / "data"
    database = data / "coord.sqlite3"
    url = f"sqlite:///{database}"
    migrate_sync(url)
    earlier = sqlite3.connect(database)  # an earlier run's WAL, as SQLite leaves it
    try:
        earlier.execute("PRAGMA journal_mode=WAL")
        earlier.execute("PRAGMA wal_autocheckpoint=0")
        earlier.execute("INSERT INTO events (at, kind, data) VALUES (0, 'old', '{}')")
        earlier.commit()
        left = data / "sessions" / "s_0000000000000001"
        left.mkdir(parents=True)
        (left / "teleop.json").write_text("{}")
        for path in (database, database.with_name("coord.sqlite3-wal"), left / "teleop.json"):
            path.chmod(0o644)
        for folder in (data, data / "sessions", left):
            folder.chmod(0o755)
        caplog.set_level(logging.WARNING, logger="crowdteleop.coord.guard.private")
        with in_process_app(coord_config(tmp_path, database_url=url), FakeLauncher()) as client:
            assert client.get("/health").status_code == 200
        assert mode(database) == mode(database.with_name("coord.sqlite3-wal")) == 0o600
    finally:
        earlier.close()
    assert mode(left / "teleop.json") == 0o600
    assert mode(data) == mode(data / "sessions") == mode(left) == 0o700
    tightened = [r.getMessage() for r in caplog.records if "tightened" in r.getMessage()]
    assert any(f"{database} from 0644 to 0600" in m for m in tightened), tightened
    assert any(f"{data} from 0755 to 0700" in m for m in tightened), tightened


def test_a_private_file_replacing_a_readable_one_is_never_readable_with_the_new_secret(
    tmp_path,
):
    path = tmp_path / "teleop.json"
    path.write_text("old, public")
    path.chmod(0o644)
    write_private(path, '{"token": "new secret"}')
    assert mode(path) == 0o600
    assert path.read_text() == '{"token": "new secret"}'
    fresh = write_private(tmp_path / "fresh.json", b"secret")
    assert mode(fresh) == 0o600


def test_a_private_file_is_not_written_through_a_symlink(tmp_path):
    target = tmp_path / "elsewhere"
    target.write_text("")
    os.symlink(target, tmp_path / "teleop.json")
    with pytest.raises(OSError):
        write_private(tmp_path / "teleop.json", "secret")
    assert target.read_text() == ""
