"""Shared fixtures. Simulations are real (robosuite + MuJoCo, offscreen GL); each test closes
what it builds, since a robosuite environment holds about 1 GiB."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from xdist.remote import Producer

from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.sim.interface import Simulation
from tests.fixtures.exclusive import EXCLUSIVE, SERIAL, room
from tests.fixtures.schedule import SerialFirstScheduling
from tests.fixtures.task_plugin import task_plugin_site, with_task_plugin  # noqa: F401

_GUARD = pytest.StashKey[tuple[subprocess.Popen, Path]]()


def pytest_sessionstart(session: pytest.Session) -> None:
    """Starts the guard that keeps the run off real-time scheduling (see realtime_guard)."""
    log = Path(tempfile.mkdtemp(prefix="crowdteleop-rt-")) / "guard.log"
    guard = subprocess.Popen(
        [sys.executable, "-m", "tests.fixtures.realtime_guard", str(os.getpid()), str(log)],
        cwd=Path(__file__).parent.parent,
    )
    session.config.stash[_GUARD] = (guard, log)


def pytest_xdist_make_scheduler(config: pytest.Config, log: Producer) -> SerialFirstScheduling:
    """Modules sharing a `serial` resource on one worker, slow modules first
    (tests/fixtures/schedule.py)."""
    return SerialFirstScheduling(config, log)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[None]:
    """Setup, call and teardown of a test that measures time run alone, and of tests that
    share a machine-wide resource one at a time (tests/fixtures/exclusive.py)."""
    serial = tuple(str(mark.args[0]) for mark in item.iter_markers(SERIAL))
    with room(exclusive=item.get_closest_marker(EXCLUSIVE) is not None, serial=serial):
        yield


def pytest_terminal_summary(terminalreporter, config: pytest.Config) -> None:
    if _GUARD not in config.stash:
        return
    guard, log = config.stash[_GUARD]
    guard.terminate()
    guard.wait(timeout=10)
    lines = log.read_text().splitlines() if log.exists() else []
    moved = [line for line in lines if " reset " in line]
    if moved:
        terminalreporter.section("threads moved off real-time scheduling")
        for line in lines:
            terminalreporter.write_line(line)


@pytest.fixture
def lift_sim() -> Iterator[Simulation]:
    sim = make_simulation(SimConfig(task="lift"))
    sim.reset(seed=0)
    yield sim
    sim.close()
