"""The robosuite backend: the paper's tasks on robosuite's models and controllers."""

from crowdteleop.sim.robosuite_backend.simulation import RobosuiteSimulation

__all__ = ["RobosuiteSimulation"]
