"""Build a `Simulation` for a config, importing only the backend it needs."""

from __future__ import annotations

from typing import TYPE_CHECKING

from crowdteleop.sim.config import SimConfig
from crowdteleop.tasks import get_task

if TYPE_CHECKING:  # the interface's types load MuJoCo; a config reader should not pay for it
    from crowdteleop.sim.interface import Simulation


def make_simulation(config: SimConfig) -> Simulation:
    backend = get_task(config.task).backend
    if backend == "robosuite":
        from crowdteleop.sim.robosuite_backend import RobosuiteSimulation

        return RobosuiteSimulation(config)
    from crowdteleop.sim.mujoco_backend import MujocoSimulation

    return MujocoSimulation(config)
