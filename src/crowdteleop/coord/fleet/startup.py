"""What starting a teleop server costs on this machine, as measured: how long it takes (the
pages count down from it while a robot is prepared) and how much memory one holds (the bound
on how many warm spares `spare_servers: auto` keeps)."""

from __future__ import annotations

import statistics
from collections import deque
from pathlib import Path

DEFAULT_START_S = 10.0  # a simulation's build, before any start was measured here
DEFAULT_SERVER_BYTES = int(0.9 * 2**30)  # a teleop server's resident memory, before measured
KEPT = 20  # the most recent starts the estimate is the median of


class StartupStats:
    """Recent start times and the largest resident memory of the servers started here."""

    def __init__(self) -> None:
        self._starts: deque[float] = deque(maxlen=KEPT)
        self._server_bytes: int | None = None

    def started(self, duration_s: float, pid: int | None = None) -> None:
        """A server accepted offers `duration_s` after its launch (`pid`: its process here)."""
        self._starts.append(duration_s)
        resident = resident_bytes(pid) if pid is not None else None
        if resident is not None:
            self._server_bytes = max(self._server_bytes or 0, resident)

    def typical_start_s(self) -> float:
        """The median of the recent starts (DEFAULT_START_S before any)."""
        return statistics.median(self._starts) if self._starts else DEFAULT_START_S

    def remaining_s(self, elapsed_s: float) -> float:
        """How long a start `elapsed_s` under way will still take (at least a second)."""
        return round(max(1.0, self.typical_start_s() - elapsed_s), 1)

    @property
    def server_bytes(self) -> int:
        """One server's memory: the largest measured, or DEFAULT_SERVER_BYTES."""
        return self._server_bytes or DEFAULT_SERVER_BYTES


def resident_bytes(pid: int) -> int | None:
    """A process's resident memory (Linux's /proc; None elsewhere or once it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def available_bytes() -> int | None:
    """Memory the machine can give new processes now (Linux's MemAvailable; None elsewhere)."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None
