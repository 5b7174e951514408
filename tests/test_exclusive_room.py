"""The lock that lets `make test` run two workers: a test that measures time is alone in the
room, the others share it (tests/fixtures/exclusive.py)."""

from __future__ import annotations

import os
import secrets
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).parents[1]

# Holds the room (shared or alone), logging in and out; the exclusive one waits for the other
# to be queued at the door before it leaves, so the order below is forced, not timed.
HOLDER = """
import sys, time
from pathlib import Path
from tests.fixtures.exclusive import room
log, name, wait_for = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
exclusive = name == "alone"
serial = ("ray",) if name.startswith("ray") else ()
with log.open("a") as out:
    out.write(f"{name} at the door\\n"); out.flush()
    with room(exclusive, serial):
        out.write(f"{name} in\\n"); out.flush()
        while wait_for and wait_for + " at the door" not in log.read_text():
            time.sleep(0.01)
        time.sleep(0.2)
        out.write(f"{name} out\\n"); out.flush()
"""


def _holder(log: Path, name: str, wait_for: str, run: str) -> subprocess.Popen[str]:
    env = {**os.environ, "PYTEST_XDIST_TESTRUNUID": run, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(log), name, wait_for], cwd=ROOT, env=env, text=True
    )


def _until(log: Path, line: str) -> None:
    deadline = time.monotonic() + 30
    while line not in (log.read_text() if log.exists() else ""):
        assert time.monotonic() < deadline, f"never: {line}"
        time.sleep(0.01)


def test_a_test_that_measures_time_has_the_room_to_itself(tmp_path):
    log, run = tmp_path / "log", secrets.token_hex(4)
    alone = _holder(log, "alone", "shared", run)
    _until(log, "alone in")
    shared = _holder(log, "shared", "", run)
    assert alone.wait(30) == 0 and shared.wait(30) == 0
    lines = log.read_text().splitlines()
    assert lines.index("alone out") < lines.index("shared in"), lines


def test_a_waiting_exclusive_test_is_let_in_before_newcomers(tmp_path):
    """The turnstile: once a test that measures time waits, a test arriving after it does not
    slip into the shared room ahead of it (the other worker cannot starve it)."""
    log, run = tmp_path / "log", secrets.token_hex(4)
    first = _holder(log, "shared", "late", run)  # in the room until the newcomer queues up
    _until(log, "shared in")
    alone = _holder(log, "alone", "", run)
    _until(log, "alone at the door")
    late = _holder(log, "late", "", run)
    assert first.wait(30) == 0 and alone.wait(30) == 0 and late.wait(30) == 0
    lines = log.read_text().splitlines()
    assert lines.index("shared out") < lines.index("alone in") < lines.index("alone out"), lines
    assert lines.index("alone out") < lines.index("late in"), lines


def test_tests_naming_one_resource_never_run_at_once(tmp_path):
    """Two Ray tests (each ends every cluster on the machine when it stops its own) on two
    workers: the second starts only once the first is done, though neither is exclusive."""
    log, run = tmp_path / "log", secrets.token_hex(4)
    first = _holder(log, "ray-1", "ray-2", run)  # in until the second queues up
    _until(log, "ray-1 in")
    second = _holder(log, "ray-2", "", run)
    assert first.wait(30) == 0 and second.wait(30) == 0
    lines = log.read_text().splitlines()
    assert lines.index("ray-1 out") < lines.index("ray-2 in"), lines
