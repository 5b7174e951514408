"""Wait for a child process's `READY <url>` line (what `crowdteleop serve` and `teleop-server`
print once they take requests), and keep draining its stdout so it never blocks on a full pipe."""

from __future__ import annotations

import signal
import subprocess
import threading
import time
from pathlib import Path


def wait_ready(
    process: subprocess.Popen[str], log_path: Path | None, timeout: float, what: str
) -> str:
    """The URL of the READY line; kills the process and raises with its log's tail if none."""
    found: list[str] = []

    def read() -> None:
        assert process.stdout is not None
        for line in process.stdout:
            if line.startswith("READY ") and not found:
                found.append(line.split()[1])

    threading.Thread(target=read, daemon=True).start()
    deadline = time.monotonic() + timeout
    while not found and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.05)
    if not found:
        process.kill()
        tail = log_path.read_text(errors="replace")[-3000:] if log_path else ""
        raise RuntimeError(f"{what} did not start:\n{tail}")
    return found[0]


def stop_gracefully(process: subprocess.Popen[str], timeout: float) -> None:
    """SIGINT (the servers finish their recordings and stop their children), then SIGKILL."""
    if process.poll() is not None:
        return
    process.send_signal(signal.SIGINT)
    try:
        process.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()
