"""robosuite's own step, for tasks the fast path cannot fold.

A task whose environment runs its own code inside a step (robosuite's ``_pre_action`` or
``_post_action`` overridden, as Wipe's markers are) needs robosuite's ``env.step``: the fast
path steps MuJoCo in C and would skip that code. Same interface as `FastStepper`.
"""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt


class PlainStepper:
    """``env.step(action)``: robosuite's controllers at every substep, its env code after."""

    def __init__(self, env: Any) -> None:
        self._env = env
        robot = env.robots[0]
        arm = robot.arms[0]
        self._arm = robot.composite_controller.part_controllers[arm]
        self._gripper: Any = robot.gripper[arm]
        self._closed = np.sign(self._gripper.format_action(np.array([1.0])))
        self._arm_qpos = np.array(robot._ref_joint_pos_indexes)
        self.initial_joints = np.zeros(len(self._arm_qpos))

    def start_episode(self, data: mujoco.MjData) -> None:
        self.initial_joints = data.qpos[self._arm_qpos].copy()
        self.gripper_command = 0.0

    @property
    def gripper_command(self) -> float:
        """robosuite's ramped finger command, +1 closed (as `FastStepper` keeps it)."""
        return float(self._closed[0] * self._gripper.current_action[0])

    @gripper_command.setter
    def gripper_command(self, value: float) -> None:
        self._gripper.current_action = self._closed * value

    def step(self, data: mujoco.MjData, action: npt.NDArray[np.float64]) -> None:
        del data  # robosuite steps its own (the same) data
        self._env.step(action)

    def state_loaded(self) -> None:
        """robosuite's controllers cache the arm's pose: read it again after a state is set."""
        self._arm.update(force=True)
