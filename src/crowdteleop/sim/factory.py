"""Build a `Simulation` for a config, importing only the backend it needs."""

from __future__ import annotations

from crowdteleop.sim.config import SimConfig
from crowdteleop.sim.interface import Simulation
from crowdteleop.sim.registry import get_task


def make_simulation(config: SimConfig) -> Simulation:
    backend = get_task(config.task).backend
    if backend == "robosuite":
        from crowdteleop.sim.robosuite_backend import RobosuiteSimulation

        return RobosuiteSimulation(config)
    from crowdteleop.sim.mujoco_backend import MujocoSimulation

    return MujocoSimulation(config)
