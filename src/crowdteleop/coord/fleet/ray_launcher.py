"""Teleop servers on a Ray cluster (issue 14): each session's server is a process owned by a
detached, named Ray actor, placed by Ray on a node with a free `teleop` slot.

- **Placement**: every actor asks for one unit of the custom resource `teleop` (a node
  offers as many as it can hold sessions, `ray start --resources='{"teleop": 4}'`) and a CPU
  share. Capacity is the cluster's `teleop` total, read again at every reaper sweep, not a
  config number. A queue longer than the free slots is handed to Ray's autoscaler
  (`request_resources`).
- **The process**: the actor runs the same `LocalProcessLauncher` as one machine does, on its
  node, so the server dies with its actor (PR_SET_PDEATHSIG). Ray does not watch an actor's
  child process: the actor does, and says so when asked.
- **Liveness**: a watcher per handle asks the actor every `watch_interval_s`. Two failed
  answers in a row (the node is gone, or the actor died) mark the server dead. The reaper then
  treats it like an exited process: the session is queued again at its place, its worker told.
- **Addresses**: a server listens on `CROWDTELEOP_TELEOP_HOST` from its node's environment
  (set where the raylet starts), else on `CoordConfig.teleop_host`: each node says how the
  workers' browsers reach it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import signal
import threading
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field

from crowdteleop.coord.fleet.cluster_checks import ClusterSetupError, TeleopNode, cluster_problems
from crowdteleop.coord.fleet.launcher import (
    LaunchError,
    LocalHandle,
    LocalProcessLauncher,
    TeleopHandle,
)
from crowdteleop.coord.guard.tls import local_names
from crowdteleop.teleop.config import TeleopConfig

log = logging.getLogger(__name__)

TELEOP_RESOURCE = "teleop"
PREFIX = "teleop-"  # actor names: teleop-<session id>-<8 hex>
HOST_VARIABLE = "CROWDTELEOP_TELEOP_HOST"


class RayLauncherConfig(BaseModel):
    """Where the Ray cluster is, and what each session asks of it."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    address: str = Field("auto", description="the cluster's GCS address (ray.init(address=...))")
    namespace: str = Field("crowdteleop", description="named actors live in this namespace")
    cpus_per_session: float = Field(0.5, gt=0, le=64, description="CPU share of one session")
    gpus_per_session: float = Field(
        0.0,
        ge=0,
        le=8,
        description="GPU share of one session (e.g. 0.125: eight per GPU); its server then "
        "renders with EGL on the GPU Ray gives it (crowdteleop.gl picks egl where a GPU "
        "driver is present)",
    )
    node_work_dir: Path = Field(
        Path("/tmp/crowdteleop-ray"), description="where a node keeps its servers' configs/logs"
    )
    shared_storage: bool = Field(
        False,
        description="`data_dir` is on storage every node mounts at the same path (NFS): "
        "episodes may then be stored locally on a cluster of several machines",
    )
    start_timeout_s: float = Field(180.0, gt=0, description="placement plus server start")
    watch_interval_s: float = Field(1.0, gt=0, description="how often each actor is asked")


class TeleopServerActor:
    """One teleop server process on this actor's node (made a Ray actor by `_actor_class`)."""

    def __init__(self, work_dir: str, default_host: str) -> None:
        host = os.environ.get(HOST_VARIABLE, default_host)
        self.launcher = LocalProcessLauncher(Path(work_dir), host=host)
        self.handle: LocalHandle | None = None

    async def start(self, config_json: str) -> dict[str, Any]:
        self.handle = await self.launcher.start(TeleopConfig.model_validate_json(config_json))
        info = await self.info()
        assert info is not None
        return info

    async def info(self) -> dict[str, Any] | None:
        """Where the server is, for a coordinator taking it back after a restart; None if
        it is gone."""
        import ray

        if not await self.alive():
            return None
        assert self.handle is not None
        node = ray.get_runtime_context().get_node_id()
        return {"url": self.handle.url, "node_id": node, "pid": self.handle.pid}

    async def alive(self) -> bool:
        return self.handle is not None and self.launcher.alive(self.handle)

    async def stop(self, grace_s: float | None) -> None:
        if self.handle is not None:
            await self.launcher.stop(self.handle, grace_s)


@dataclass
class RayHandle:
    url: str
    name: str  # the actor's name in the launcher's namespace
    node_id: str
    pid: int  # the server process's, on its node
    actor: Any = field(repr=False)
    alive: bool = True
    watcher: asyncio.Task[None] | None = field(default=None, repr=False)


def _actor_class() -> Any:
    import ray

    return ray.remote(TeleopServerActor)


class RayLauncher:
    """The `Launcher` of a Ray cluster; see the module's docstring."""

    def __init__(self, config: RayLauncherConfig, teleop_host: str) -> None:
        import ray

        self.config = config
        self.teleop_host = teleop_host
        if not ray.is_initialized():
            # ray.init makes SIGTERM `sys.exit` (an abort, exit 134, in a running server):
            # the server's own handler stays, so `systemctl stop` is a graceful stop.
            on_sigterm = signal.getsignal(signal.SIGTERM)
            ray.init(
                address=config.address,
                namespace=config.namespace,
                log_to_driver=False,
                configure_logging=False,
            )
            if on_sigterm is not None and threading.current_thread() is threading.main_thread():
                signal.signal(signal.SIGTERM, on_sigterm)
        self._actor = _actor_class()

    def capacity(self) -> int:
        """The cluster's `teleop` slots now (nodes come and go)."""
        import ray

        resources: dict[str, float] = ray.cluster_resources()  # type: ignore[no-untyped-call]
        return int(resources.get(TELEOP_RESOURCE, 0))

    def teleop_nodes(self) -> list[TeleopNode]:
        """The live nodes offering teleop slots, by the address each announced."""
        import ray

        return [
            TeleopNode(node["NodeManagerAddress"], int(node["Resources"][TELEOP_RESOURCE]))
            for node in ray.nodes()  # type: ignore[no-untyped-call]
            if node.get("Alive") and node.get("Resources", {}).get(TELEOP_RESOURCE)
        ]

    def check(self, report_url: str, episodes_shared: bool) -> None:
        """Refuse to serve a campaign the cluster's nodes could not record (cluster_checks)."""
        nodes = self.teleop_nodes()
        problems = cluster_problems(nodes, report_url, episodes_shared, set(local_names()))
        if problems:
            raise ClusterSetupError("; and ".join(problems))
        where = ", ".join(f"{n.address} ({n.slots})" for n in nodes) or "none yet"
        log.info("Ray nodes with teleop slots: %s; reports go to %s", where, report_url)

    def request(self, sessions: int) -> None:
        """Ask the autoscaler for room for `sessions` at once (a no-op without one)."""
        from ray.autoscaler.sdk import request_resources

        with contextlib.suppress(Exception):  # no autoscaler: nothing to ask
            request_resources(bundles=[{TELEOP_RESOURCE: 1}] * sessions)

    async def start(self, config: TeleopConfig) -> RayHandle:
        name = f"{PREFIX}{config.session_id}-{uuid.uuid4().hex[:8]}"
        actor = self._actor.options(
            name=name,
            lifetime="detached",
            num_cpus=self.config.cpus_per_session,
            num_gpus=self.config.gpus_per_session,
            resources={TELEOP_RESOURCE: 1},
            max_restarts=0,
        ).remote(str(self.config.node_work_dir), self.teleop_host)
        try:
            info = await asyncio.wait_for(
                actor.start.remote(config.model_dump_json()), self.config.start_timeout_s
            )
        except (Exception, asyncio.CancelledError) as exc:
            self._kill(actor)
            if isinstance(exc, asyncio.CancelledError):
                raise
            raise LaunchError(f"teleop server for {config.session_id} on Ray: {exc}") from exc
        handle = self._watched(name, actor, info)
        log.info("teleop server %s on node %s at %s", name, handle.node_id[:12], handle.url)
        return handle

    def _watched(self, name: str, actor: Any, info: dict[str, Any]) -> RayHandle:
        handle = RayHandle(info["url"], name, info["node_id"], info["pid"], actor)
        handle.watcher = asyncio.create_task(self._watch(handle), name=f"watch-{name}")
        return handle

    async def _actors(self) -> dict[str, str]:
        """This namespace's teleop server actors: name -> session id."""
        from ray.util import list_named_actors

        names: list[str] = await asyncio.to_thread(list_named_actors)
        return {n: n.removeprefix(PREFIX).rsplit("-", 1)[0] for n in names if n.startswith(PREFIX)}

    async def reattach(self, session_id: str, name: str | None = None) -> RayHandle | None:
        import ray

        actors = await self._actors()
        for candidate in [n for n, owner in actors.items() if n == name or owner == session_id]:
            info: dict[str, Any] | None
            try:
                actor = ray.get_actor(candidate)
                info = await asyncio.wait_for(actor.info.remote(), 10)
            except (Exception, TimeoutError):
                info = None
            if info is not None:
                return self._watched(candidate, actor, info)
        return None

    def name_of(self, handle: TeleopHandle) -> str:
        assert isinstance(handle, RayHandle)
        return handle.name

    async def stop_others(self, keep: set[str]) -> int:
        import ray

        stopped = 0
        for name, owner in (await self._actors()).items():
            if owner not in keep and name not in keep:
                with contextlib.suppress(Exception):
                    self._kill(ray.get_actor(name))
                    stopped += 1
        if stopped:
            log.warning("stopped %d teleop servers no live session holds", stopped)
        return stopped

    def release(self, handle: TeleopHandle) -> None:
        assert isinstance(handle, RayHandle)
        if handle.watcher is not None:
            handle.watcher.cancel()

    async def _watch(self, handle: RayHandle) -> None:
        """Ask the actor until it fails to answer twice in a row; then it is dead."""
        failures = 0
        while failures < 2:
            await asyncio.sleep(self.config.watch_interval_s)
            try:
                answer = await asyncio.wait_for(
                    handle.actor.alive.remote(), self.config.watch_interval_s
                )
            except (Exception, TimeoutError):  # the actor or its node is gone, or unreachable
                answer = False
            failures = 0 if answer else failures + 1
        handle.alive = False
        log.warning("teleop server %s (node %s) is gone", handle.name, handle.node_id[:12])

    async def stop(self, handle: TeleopHandle, grace_s: float | None = None) -> None:
        assert isinstance(handle, RayHandle)
        if handle.watcher is not None:
            handle.watcher.cancel()
        if handle.alive:
            with contextlib.suppress(Exception, TimeoutError):
                await asyncio.wait_for(handle.actor.stop.remote(grace_s), (grace_s or 0) + 10)
        handle.alive = False
        self._kill(handle.actor)

    @staticmethod
    def _kill(actor: Any) -> None:
        import ray

        with contextlib.suppress(Exception):
            ray.kill(actor, no_restart=True)

    def alive(self, handle: TeleopHandle) -> bool:
        assert isinstance(handle, RayHandle)
        return handle.alive
