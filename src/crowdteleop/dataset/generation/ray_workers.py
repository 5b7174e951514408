"""Generation attempts on Ray actors: each actor builds its simulation once and runs attempts
as they are handed out, anywhere on the cluster (``--ray ADDRESS``), or on a local Ray it
starts itself (``--ray local``). The attempts' results come back to this process, which alone
writes episodes and the log, so a resumed run is the same whichever ran them.

Ray has no authentication and listens on every interface: run a cluster only where its ports
are private (docs/learning.md); the test runs one in a loopback-only network namespace.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from crowdteleop.dataset.generation.worker import GenerationWorker

if TYPE_CHECKING:
    from crowdteleop.dataset.generation.attempt import Attempt, Settings


class GenerationActor:
    """One simulation on a Ray worker (wrapped by ``ray.remote`` at run time)."""

    def __init__(self, dataset: bytes, settings: Settings) -> None:
        import tempfile

        # the source dataset travels through Ray's object store: a node need not share disks
        self._folder = tempfile.TemporaryDirectory(prefix="crowdteleop-generate-")
        path = Path(self._folder.name) / "source.hdf5"
        path.write_bytes(dataset)
        self._worker = GenerationWorker(path, settings)

    def attempt(self, index: int, seed: int) -> Attempt:
        import os

        import ray

        node = ray.get_runtime_context().get_node_id()
        return self._worker.attempt(index, seed, f"ray node {node[:12]}:{os.getpid()}")


def run_on_ray(
    source: Path,
    address: str,
    workers: int,
    settings: Settings,
    seed: int,
    pending: Iterator[int],
    record: Callable[[Attempt], None],
    enough: Callable[[], bool],
) -> None:
    """As the process pool does, with ``workers`` actors (one CPU each) on the cluster at
    ``address`` ("local": one started here); attempt ``i`` is scene ``seed + i``."""
    import ray

    started_here = not ray.is_initialized()
    if started_here:
        ray.init(
            address=None if address == "local" else address,
            include_dashboard=False,
            log_to_driver=False,
        )
    try:
        actor_class = ray.remote(num_cpus=1)(GenerationActor)
        dataset = ray.put(Path(source).read_bytes())
        actors: list[Any] = [  # ActorHandle[GenerationActor]: Ray's stubs do not type methods
            actor_class.remote(dataset, settings) for _ in range(workers)
        ]
        running: dict[Any, Any] = {}  # object ref -> actor
        idle = list(actors) * 2  # two attempts queued per actor keep it busy
        while True:
            while idle and not enough():
                index = next(pending, None)
                if index is None:
                    break
                actor = idle.pop()
                running[actor.attempt.remote(index, seed + index)] = actor
            if not running:
                return
            ready, _ = ray.wait(list(running), num_returns=1)
            for ref in ready:
                idle.append(running.pop(ref))
                record(ray.get(ref))
            if enough():
                for ref in list(running):
                    record(ray.get(ref))
                return
    finally:
        if started_here:
            ray.shutdown()
