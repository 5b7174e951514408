"""What runs attempts: one simulation and the sources' segments, built once per process (or
Ray actor) and reused for every attempt it is handed."""

from __future__ import annotations

import os
import socket
from pathlib import Path

from crowdteleop.dataset.absolute import AbsoluteTargets
from crowdteleop.dataset.generation.attempt import Attempt, Scene, Settings, run_attempt
from crowdteleop.dataset.generation.segments import common_subtasks
from crowdteleop.dataset.generation.sources import read_sources
from crowdteleop.dataset.replay import ReplayChecker, recorded_env_args


class GenerationWorker:
    """One process's simulation and sources."""

    def __init__(self, source: Path, settings: Settings) -> None:
        sources = read_sources(source)
        self._checker = ReplayChecker()
        sim = self._checker.simulation(sources.first, robosuite_step=settings.robosuite_step)
        subtasks, segments, _ = common_subtasks(sources.demos)
        from crowdteleop.tasks import get_task

        task = get_task(sources.metadata.task)
        arm = recorded_env_args(sources.first).arm
        assert arm is not None  # an OSC recording (read_sources)
        self.scene = Scene(
            sim,
            AbsoluteTargets(sim.kinematics(), arm),
            subtasks,
            segments,
            round(task.time_limit_s / sim.control_dt),
            settings,
            dict(task.symmetric_objects),
        )

    def attempt(self, index: int, seed: int, where: str = "") -> Attempt:
        attempt = run_attempt(self.scene, index, seed)
        attempt.worker = where or f"{socket.gethostname()}:{os.getpid()}"
        return attempt


_WORKER: GenerationWorker | None = None  # one per pool process, built by its initializer


def start_pool_worker(source: Path, settings: Settings) -> None:
    global _WORKER  # a pool process's own simulation, built once by the pool's initializer
    _WORKER = GenerationWorker(source, settings)


def run_pool_attempt(index: int, seed: int) -> Attempt:
    assert _WORKER is not None
    return _WORKER.attempt(index, seed)
