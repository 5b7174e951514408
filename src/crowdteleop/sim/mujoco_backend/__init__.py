"""The pure-MuJoCo backend: a hand-written scene on the `mujoco` bindings alone."""

from crowdteleop.sim.mujoco_backend.objects import MujocoScene
from crowdteleop.sim.mujoco_backend.simulation import MujocoSimulation

__all__ = ["MujocoScene", "MujocoSimulation"]
