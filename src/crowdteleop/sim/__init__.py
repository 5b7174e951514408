"""The simulation core: named tasks behind one `Simulation` interface.

sim = make_simulation(SimConfig(task="lift", robot="Sawyer"))
sim.reset(seed=0)
frame = sim.render("frontview", 320, 240)
"""

from crowdteleop.sim.config import SimConfig
from crowdteleop.sim.factory import make_simulation
from crowdteleop.sim.interface import Simulation
from crowdteleop.sim.registry import TASKS, TaskSpec, get_task

__all__ = ["TASKS", "SimConfig", "Simulation", "TaskSpec", "get_task", "make_simulation"]
