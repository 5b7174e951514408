"""The test run's guard moves a process of the run that something put on real-time scheduling
back to the normal scheduler (see tests/fixtures/realtime_guard.py for why)."""

from __future__ import annotations

import os
import subprocess
import time

import pytest


def test_a_child_put_on_fifo_is_moved_back_within_a_second() -> None:
    if os.geteuid() != 0:
        pytest.skip("setting SCHED_FIFO on a process needs root (CI runs as root)")
    child = subprocess.Popen(["sleep", "30"])
    try:
        os.sched_setscheduler(child.pid, os.SCHED_FIFO, os.sched_param(50))
        assert os.sched_getscheduler(child.pid) == os.SCHED_FIFO
        started = time.monotonic()
        while os.sched_getscheduler(child.pid) != os.SCHED_OTHER:
            assert time.monotonic() - started < 2.0, "the guard left the child on SCHED_FIFO"
            time.sleep(0.05)
    finally:
        child.kill()
        child.wait()
