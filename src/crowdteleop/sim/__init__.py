"""The simulation core: named tasks behind one `Simulation` interface.

sim = make_simulation(SimConfig(task="lift", robot="Sawyer"))
sim.reset(seed=0)
frame = sim.render("frontview", 320, 240)

Importing this package loads no simulator (the coordinator reads `SimConfig` without MuJoCo);
`make_simulation` imports the backend a task needs. The interface is `crowdteleop.sim.interface`.
"""

from crowdteleop.sim.config import SimConfig
from crowdteleop.sim.factory import make_simulation

__all__ = ["SimConfig", "make_simulation"]
