"""Other robosuite arms are selectable and drive like the default Sawyer."""

from __future__ import annotations

import numpy as np
import pytest

from crowdteleop.sim import SimConfig, make_simulation
from tests.fixtures.motion import arm_motion


@pytest.mark.parametrize("robot", ["Panda", "UR5e", "IIWA"])
def test_other_arms_reset_step_and_render(robot):
    sim = make_simulation(SimConfig(task="pick-place-can", robot=robot))
    try:
        sim.reset(seed=0)
        start = sim.robot_state().end_effector.position
        for index in range(10):
            sim.step(arm_motion(sim, index))
        assert np.linalg.norm(sim.robot_state().end_effector.position - start) > 0.01
        assert sim.render("agentview", 160, 120).std() > 20
    finally:
        sim.close()
