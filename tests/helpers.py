"""Small helpers the tests share."""

from __future__ import annotations

import numpy as np

from crowdteleop.sim.interface import Simulation


def arm_motion(sim: Simulation, step_index: int) -> np.ndarray:
    """An action that visibly moves the arm in either action mode, gripper closing."""
    action = np.zeros(sim.action_spec.size)
    if sim.action_spec.mode == "joint-velocity":
        action[:-1] = 0.6 * np.sin(0.3 * step_index + np.arange(sim.action_spec.size - 1))
    else:
        action[:3] = [0.4, -0.3, 0.2]
    action[-1] = 1.0
    return action
