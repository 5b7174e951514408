"""How `crowdteleop serve` ends, as a process manager sees it (issue 30): `systemctl stop`
(SIGTERM) and Ctrl-C (SIGINT) are the same graceful stop, exit 0; a coordinator that cannot
start (its database away, a cluster it cannot serve) exits 3 and says so, instead of exiting
0 as if stopped. The Ray launcher's case (Ray's own SIGTERM handler) is in
tests/coord/test_deploy_guide.py."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from tests.coord.test_coord_settings import ready_url
from tests.fixtures.coord import ADMIN


def serve(tmp_path, *flags: str) -> tuple[subprocess.Popen[bytes], list]:
    out, log = tmp_path / "serve.out", tmp_path / "serve.log"
    command = [sys.executable, "-m", "crowdteleop", "serve", "--port", "0"]
    command += ["--data-dir", str(tmp_path / "data"), "--admin-token", ADMIN, *flags]
    with out.open("w") as stdout, log.open("w") as stderr:
        process = subprocess.Popen(command, stdout=stdout, stderr=stderr, cwd=tmp_path)
    return process, [out, log]


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_stop_signal_is_a_graceful_stop_with_exit_0(tmp_path, stop):
    process, (out, log) = serve(tmp_path)
    ready_url(out, process, log)
    process.send_signal(stop)
    assert process.wait(timeout=30) == 0, log.read_text()[-2000:]
    assert "left" in log.read_text(), "the lifespan's shutdown ran (the replica said goodbye)"


def test_a_coordinator_that_cannot_start_exits_3_and_says_so(tmp_path):
    process, (_out, log) = serve(tmp_path, "--database-url", "postgresql://nobody@127.0.0.1:1/x")
    assert process.wait(timeout=60) == 3
    text = log.read_text()
    assert "the coordinator did not start" in text
    assert "Connection refused" in text or "connection" in text.lower(), text[-2000:]
