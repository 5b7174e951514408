"""`crowdteleop serve`'s settings come from one rule (issue 30, item 2): defaults < the --config
file < CROWDTELEOP_<FIELD> variables < flags given. A flag not given overrides nothing, and the
defaults that follow from other settings follow from their effective values."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from typer.testing import CliRunner

from crowdteleop.cli import app
from crowdteleop.coord.cli import ServeOptions, Settings, effective_settings, given_settings
from crowdteleop.coord.service.config import ENV_PREFIX, CoordConfig
from tests.fixtures.coord import auth

FILE_TOKEN = "file-token-9fK2xqLm3Pz7Rt0Vw5Yb8"
ENV_TOKEN = "env-token-Qa7Zc1Xv9Bn3Mm5Kl0Jh"
FLAG_TOKEN = "flag-token-Ty6Ui8Op2As4Df7Gh1"
VARIABLES = {f"{ENV_PREFIX}{name.upper()}" for name in CoordConfig.model_fields}


@pytest.fixture(autouse=True)
def no_coord_variables(monkeypatch):
    """The developer's own CROWDTELEOP_<FIELD> variables would be a layer of every test."""
    for name in VARIABLES:
        monkeypatch.delenv(name, raising=False)


def config_file(tmp_path: Path, **fields: Any) -> Path:
    path = tmp_path / "coord.json"
    path.write_text(json.dumps(fields))
    return path


def settings(port: int = 8000, **options: Any) -> Settings:
    """What `serve` would run with, listening on `port`."""
    o = ServeOptions(port=port, **options)
    return effective_settings(o, given_settings(o), port)


def print_config(*args: str) -> dict[str, tuple[str, str]]:
    """`serve --print-config`'s rows: setting -> (from, value)."""
    run = CliRunner().invoke(app, ["serve", *args, "--print-config"])
    assert run.exit_code == 0, run.output
    rows = {}
    for line in run.stdout.splitlines():
        cells = re.split(r"\s{2,}", line.strip())
        if len(cells) == 3 and cells[0] in CoordConfig.model_fields:
            rows[cells[0]] = (cells[1], cells[2])
    assert set(rows) == set(CoordConfig.model_fields), run.stdout
    return rows


def test_the_files_token_data_dir_and_public_url_are_the_effective_ones(tmp_path):
    store = tmp_path / "store"
    path = config_file(
        tmp_path, admin_token=FILE_TOKEN, data_dir=str(store), public_url="https://s.example.org"
    )
    config = settings(config=path).config
    assert config.admin_token == FILE_TOKEN
    assert config.data_dir == store
    assert config.public_url == "https://s.example.org"
    assert not settings(config=path).token_made_up, "the file's token is not printed"

    rows = print_config("--config", str(path))
    assert rows["admin_token"] == (f"file {path}", "***")
    assert rows["data_dir"] == (f"file {path}", str(store))
    assert rows["public_url"] == (f"file {path}", "https://s.example.org")
    assert rows["capacity"] == ("default", "2")


def test_a_flag_given_overrides_the_file(tmp_path):
    path = config_file(tmp_path, admin_token=FILE_TOKEN, capacity=3, public_url="https://f.org")
    got = settings(config=path, admin_token=FLAG_TOKEN, capacity=5)
    assert (got.config.admin_token, got.config.capacity) == (FLAG_TOKEN, 5)
    assert got.config.public_url == "https://f.org", "a flag not given overrides nothing"

    rows = print_config("--config", str(path), "--capacity", "5")
    assert rows["capacity"] == ("flag --capacity", "5")
    assert rows["public_url"] == (f"file {path}", "https://f.org")


def test_the_environment_overrides_the_file(tmp_path, monkeypatch):
    path = config_file(tmp_path, admin_token=FILE_TOKEN, capacity=3, teleop_host="10.0.0.2")
    monkeypatch.setenv("CROWDTELEOP_ADMIN_TOKEN", ENV_TOKEN)
    monkeypatch.setenv("CROWDTELEOP_CAPACITY", "7")
    monkeypatch.setenv("CROWDTELEOP_TELEOP_HOST", "10.0.0.9")  # a Ray node's variable too
    monkeypatch.setenv("CROWDTELEOP_RAY", '{"address": "auto", "cpus_per_session": 0.25}')
    monkeypatch.setenv("CROWDTELEOP_PUBLIC_URL", "")  # empty: unset
    config = settings(config=path).config
    assert (config.admin_token, config.capacity, config.teleop_host) == (ENV_TOKEN, 7, "10.0.0.9")
    assert config.ray is not None and config.ray.cpus_per_session == 0.25
    assert config.public_url == "http://127.0.0.1:8000"

    rows = print_config("--config", str(path))
    assert rows["capacity"] == ("environment CROWDTELEOP_CAPACITY", "7")
    assert rows["admin_token"] == ("environment CROWDTELEOP_ADMIN_TOKEN", "***")
    assert rows["public_url"][0] == "default (from --host, --port)"


def test_a_flag_given_overrides_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("CROWDTELEOP_ADMIN_TOKEN", ENV_TOKEN)
    monkeypatch.setenv("CROWDTELEOP_DATA_DIR", str(tmp_path / "env"))
    got = settings(admin_token=FLAG_TOKEN)
    assert got.config.admin_token == FLAG_TOKEN
    assert got.config.data_dir == tmp_path / "env"

    rows = print_config("--data-dir", str(tmp_path / "flag"))
    assert rows["data_dir"] == ("flag --data-dir", str(tmp_path / "flag"))
    assert rows["admin_token"] == ("environment CROWDTELEOP_ADMIN_TOKEN", "***")


def test_the_sqlite_default_is_under_the_effective_data_dir(tmp_path, monkeypatch):
    path = config_file(tmp_path, admin_token=FILE_TOKEN, data_dir=str(tmp_path / "store"))
    database = f"sqlite:///{tmp_path / 'store' / 'coord.sqlite3'}"
    assert settings(config=path).config.database_url == database
    assert print_config("--config", str(path))["database_url"][1] == database
    monkeypatch.setenv("CROWDTELEOP_DATA_DIR", str(tmp_path / "env"))
    database = f"sqlite:///{tmp_path / 'env' / 'coord.sqlite3'}"
    assert settings(config=path).config.database_url == database
    given = settings(config=path, database_url="sqlite:////elsewhere.sqlite3").config
    assert given.database_url == "sqlite:////elsewhere.sqlite3"


def test_with_ray_and_no_internal_url_teleop_servers_report_to_the_public_url(tmp_path):
    path = config_file(tmp_path, ray={"address": "auto"}, public_url="https://lb.example.org/")
    got = settings(config=path, admin_token=FLAG_TOKEN)
    assert got.config.internal_url is None
    assert got.config.report_base_url == "https://lb.example.org"
    path = config_file(tmp_path, ray={"address": "auto"}, internal_url="http://10.0.0.5:8000")
    got = settings(config=path, admin_token=FLAG_TOKEN)
    assert got.config.report_base_url == "http://10.0.0.5:8000", "a layer's internal_url stays"


def test_without_ray_teleop_servers_report_to_loopback(tmp_path):
    got = settings(port=8123, admin_token=FLAG_TOKEN, host="0.0.0.0")
    assert got.config.internal_url == "http://127.0.0.1:8123"
    assert got.config.report_base_url == "http://127.0.0.1:8123"
    assert got.origins["internal_url"].startswith("default")


def test_a_token_no_layer_gives_is_random_and_printed():
    first, second = settings(), settings()
    assert first.token_made_up and second.token_made_up
    assert first.config.admin_token != second.config.admin_token


def test_print_config_masks_secrets_and_binds_nothing(tmp_path):
    path = config_file(
        tmp_path,
        admin_token=FILE_TOKEN,
        database_url="postgresql://coord:hunter2-secret@db.example.org/coord",
        turn={"urls": ["turn:t.example.org:3478"], "secret": "turn-secret-0123456789abcdef"},
        ice_servers=[{"urls": "turn:u.example.org", "username": "u", "credential": "pw-4567"}],
    )
    with socket.socket() as busy:  # the port is taken: --print-config does not mind
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        run = CliRunner().invoke(
            app, ["serve", "--config", str(path), "--port", str(port), "--print-config"]
        )
    assert run.exit_code == 0, run.output
    for secret in (FILE_TOKEN, "hunter2-secret", "turn-secret-0123456789abcdef", "pw-4567"):
        assert secret not in run.stdout
    assert "postgresql://coord:***@db.example.org/coord" in run.stdout
    assert f"127.0.0.1:{port}" in run.stdout


@pytest.mark.parametrize(
    ("variables", "args", "named"),
    [
        ({"CROWDTELEOP_CAPACITY": "lots"}, [], "CROWDTELEOP_CAPACITY"),
        ({"CROWDTELEOP_RAY": "{not json"}, [], "CROWDTELEOP_RAY"),
        ({}, ["--config", "/nonexistent/coord.yaml"], "/nonexistent/coord.yaml"),
        ({}, ["--admin-token", "short"], "--admin-token"),
    ],
)
def test_bad_input_is_named_and_exits_2(monkeypatch, variables, args, named):
    for name, value in variables.items():
        monkeypatch.setenv(name, value)
    run = CliRunner().invoke(app, ["serve", *args, "--print-config"])
    assert run.exit_code == 2, run.output
    assert named in " ".join(run.output.split())
    assert "Traceback" not in run.output


def test_serve_with_a_config_file_accepts_its_admin_token_and_prints_none(tmp_path):
    """The operator's bug: the file's token got 401 and a new one was printed at each start."""
    store = tmp_path / "store"
    path = config_file(tmp_path, admin_token=FILE_TOKEN, data_dir=str(store), spare_servers=0)
    env = {name: value for name, value in os.environ.items() if name not in VARIABLES}
    out, log = tmp_path / "serve.out", tmp_path / "serve.log"
    command = [sys.executable, "-m", "crowdteleop", "serve", "--config", str(path), "--port", "0"]
    with out.open("w") as stdout, log.open("w") as stderr:
        process = subprocess.Popen(command, stdout=stdout, stderr=stderr, cwd=tmp_path, env=env)
    try:
        url = ready_url(out, process, log)
        overview = httpx.get(f"{url}/api/admin/overview", headers=auth(FILE_TOKEN), timeout=10)
        assert overview.status_code == 200, overview.text
        wrong = httpx.get(f"{url}/api/admin/overview", headers=auth(FLAG_TOKEN), timeout=10)
        assert wrong.status_code == 401
    finally:
        process.send_signal(signal.SIGINT)
        process.wait(timeout=30)
    printed = out.read_text()
    assert "admin token" not in printed and FILE_TOKEN not in printed, printed
    assert (store / "coord.sqlite3").exists(), "the database is under the file's data_dir"
    assert not (tmp_path / "data").exists(), "nothing in ./data"


def ready_url(out: Path, process: subprocess.Popen[bytes], log: Path) -> str:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and process.poll() is None:
        ready = [line for line in out.read_text().splitlines() if line.startswith("READY ")]
        if ready:
            return ready[0].split()[1]
        time.sleep(0.05)
    raise AssertionError(f"serve did not start:\n{log.read_text()[-3000:]}")
