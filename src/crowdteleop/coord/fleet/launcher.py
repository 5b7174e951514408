"""How a teleop server comes to life for one session. The coordinator only knows `Launcher`;
`LocalProcessLauncher` runs each session as a child process on this machine (the paper's one
process per worker); a cluster backend implements the same three calls."""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import logging
import os
import signal
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

from crowdteleop.coord.guard.private import open_private_log, private_dir, write_private
from crowdteleop.teleop.config import TeleopConfig

log = logging.getLogger(__name__)


def teleop_server_argv(
    config_path: Path, python: str = sys.executable, host: str | None = None, port: int = 0
) -> list[str]:
    """The command line of one teleop server process reading its config from a file."""
    address = [] if host is None else ["--host", host]
    return [
        python,
        "-m",
        "crowdteleop",
        "teleop-server",
        "--config",
        str(config_path),
        *address,
        "--port",
        str(port),
    ]


class LaunchError(RuntimeError):
    """A teleop server did not come up; the message carries the end of its log."""


@runtime_checkable
class TeleopHandle(Protocol):
    url: str


class Launcher(Protocol):
    async def start(self, config: TeleopConfig) -> TeleopHandle:
        """Start a server for `config` and return once it accepts offers."""
        ...

    async def stop(self, handle: TeleopHandle, grace_s: float | None = None) -> None:
        """Stop it and wait until it is gone (idempotent): asked to finish its recordings
        first, for `grace_s` (None: the launcher's default; 0: killed at once)."""
        ...

    def alive(self, handle: TeleopHandle) -> bool: ...


@runtime_checkable
class ClusterLauncher(Protocol):
    """A launcher whose room is a cluster's: capacity is read from it, demand is told to it."""

    def capacity(self) -> int: ...

    def request(self, sessions: int) -> None: ...


@runtime_checkable
class ReattachingLauncher(Protocol):
    """A launcher whose servers outlive the coordinator (Ray's detached actors): a restarted
    coordinator takes its running sessions' servers back instead of orphaning them."""

    async def reattach(self, session_id: str, name: str | None = None) -> TeleopHandle | None:
        """The session's running server (the one called `name`, when the session records
        it), or None (gone, or never started)."""
        ...

    def name_of(self, handle: TeleopHandle) -> str:
        """The server's name in the launcher: what `reattach` finds it by."""
        ...

    async def stop_others(self, keep: set[str]) -> int:
        """Stop every server of this launcher neither started for a session id in `keep` nor
        called by a name in it; how many."""
        ...

    def release(self, handle: TeleopHandle) -> None:
        """Stop watching the server, which keeps running for another coordinator."""
        ...


async def reattach(
    launcher: Launcher, session_id: str, name: str | None = None
) -> TeleopHandle | None:
    if not isinstance(launcher, ReattachingLauncher):
        return None
    return await launcher.reattach(session_id, name)


def server_name(launcher: Launcher, handle: TeleopHandle) -> str | None:
    """What a replica re-attaches the server by (None: only its own process can reach it)."""
    return launcher.name_of(handle) if isinstance(launcher, ReattachingLauncher) else None


async def stop_orphans(launcher: Launcher, keep: set[str]) -> int:
    if not isinstance(launcher, ReattachingLauncher):
        return 0  # local servers die with the coordinator (PR_SET_PDEATHSIG)
    return await launcher.stop_others(keep)


@dataclass
class LocalHandle:
    url: str
    process: asyncio.subprocess.Process
    log_path: Path
    drain: asyncio.Task[None] | None = field(default=None, repr=False)

    @property
    def pid(self) -> int:
        return self.process.pid


def _die_with_parent() -> None:
    """In the child, before exec: SIGTERM when the coordinator dies, even by SIGKILL."""
    with contextlib.suppress(Exception):
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


class LocalProcessLauncher:
    """`python -m crowdteleop teleop-server --config FILE --port 0`, awaiting its READY line."""

    def __init__(
        self,
        work_dir: Path,
        start_timeout_s: float = 120.0,
        stop_timeout_s: float = 15.0,
        python: str = sys.executable,
        host: str | None = None,
    ) -> None:
        self.work_dir = work_dir
        self.host = host
        self.start_timeout_s = start_timeout_s
        self.stop_timeout_s = stop_timeout_s
        self.python = python

    async def start(self, config: TeleopConfig) -> LocalHandle:
        folder = private_dir(self.work_dir / config.session_id)
        config_path = write_private(folder / "teleop.json", config.model_dump_json(indent=2))
        log_path = folder / "teleop.log"
        log_fd = open_private_log(log_path)
        try:
            process = await asyncio.create_subprocess_exec(
                *teleop_server_argv(config_path, self.python, self.host),
                stdin=asyncio.subprocess.DEVNULL,
                stdout=asyncio.subprocess.PIPE,
                stderr=log_fd,
                preexec_fn=_die_with_parent if sys.platform == "linux" else None,
                env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )
        finally:
            os.close(log_fd)
        handle = LocalHandle("", process, log_path)
        try:
            handle.url = await asyncio.wait_for(self._ready(process), self.start_timeout_s)
        except (TimeoutError, LaunchError, asyncio.CancelledError) as exc:
            await self.stop(handle)
            if isinstance(exc, asyncio.CancelledError):
                raise
            tail = log_path.read_text(errors="replace")[-2000:]
            raise LaunchError(
                f"teleop server for {config.session_id} did not start: {tail}"
            ) from exc
        handle.drain = asyncio.create_task(self._drain(process), name=f"drain-{process.pid}")
        log.info("teleop server %s for %s at %s", process.pid, config.session_id, handle.url)
        return handle

    @staticmethod
    async def _ready(process: asyncio.subprocess.Process) -> str:
        assert process.stdout is not None
        while True:
            line = (await process.stdout.readline()).decode(errors="replace")
            if not line:
                raise LaunchError(f"exited with {await process.wait()} before READY")
            if line.startswith("READY "):
                return line.split()[1]

    @staticmethod
    async def _drain(process: asyncio.subprocess.Process) -> None:
        """Keep reading stdout so a chatty child never blocks on a full pipe."""
        assert process.stdout is not None
        while await process.stdout.read(65536):
            pass

    async def stop(self, handle: TeleopHandle, grace_s: float | None = None) -> None:
        assert isinstance(handle, LocalHandle)
        process = handle.process
        grace_s = self.stop_timeout_s if grace_s is None else grace_s
        if process.returncode is None:
            # SIGINT: the server finishes its recordings. A hung (e.g. stopped) one cannot,
            # and its write-ahead log is recovered by the session's next server instead.
            with contextlib.suppress(ProcessLookupError):
                process.send_signal(signal.SIGINT if grace_s > 0 else signal.SIGKILL)
            try:
                await asyncio.wait_for(process.wait(), max(grace_s, 0.1))
            except TimeoutError:
                log.warning("teleop server %s ignored SIGINT; killing it", process.pid)
                with contextlib.suppress(ProcessLookupError):
                    process.kill()
                await process.wait()
        if handle.drain is not None:
            handle.drain.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await handle.drain

    def alive(self, handle: TeleopHandle) -> bool:
        assert isinstance(handle, LocalHandle)
        return handle.process.returncode is None
