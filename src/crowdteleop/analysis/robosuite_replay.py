"""Step recorded OSC_POSE actions in plain robosuite, to check they keep robosuite's meaning.

Plain robosuite here is robosuite's own environment with its default Sawyer controller
(OSC_POSE, Python at every substep), loaded the way robosuite's playback script loads a
demonstration: `reset_from_xml_string(model_file)`, then states.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import robosuite
from robosuite.controllers import load_composite_controller_config

from crowdteleop.sim.registry import get_task


class RobosuiteReplayer:
    """A plain robosuite environment for one task and model file."""

    def __init__(self, task: str, mjcf_xml: str, robot: str = "Sawyer", control_hz: float = 20):
        self._env = robosuite.make(
            get_task(task).env_name,
            robots=robot,
            controller_configs=load_composite_controller_config(robot=robot),
            has_renderer=False,
            has_offscreen_renderer=False,
            use_camera_obs=False,
            control_freq=control_hz,
            ignore_done=True,
            hard_reset=False,
        )
        self._env.reset_from_xml_string(mjcf_xml)
        robot_model = self._env.robots[0]
        self._arm = robot_model.composite_controller.part_controllers[robot_model.arms[0]]
        self._gripper: Any = robot_model.gripper[robot_model.arms[0]]
        self._closed = np.sign(self._gripper.format_action(np.array([1.0])))
        self._site = self._env.sim.model.site_name2id(self._gripper.important_sites["grip_site"])

    def close(self) -> None:
        self._env.close()

    def _load(self, state: np.ndarray) -> None:
        self._env.sim.set_state_from_flattened(state)
        self._env.sim.forward()

    def _step(self, action: np.ndarray) -> np.ndarray:
        # robosuite ramps its finger command 0.2 per step; start it where our (stateless) gripper
        # command is, so the comparison measures the arm.
        self._gripper.current_action = self._closed * action[-1] - (
            self._closed * self._gripper.speed * np.sign(action[-1])
        )
        self._env.step(action)
        return np.array(self._env.sim.data.site_xpos[self._site])

    def per_step(
        self, states_before: Sequence[np.ndarray], actions: np.ndarray, initial_joints: np.ndarray
    ) -> np.ndarray:
        """Hand positions after each action, each stepped from the recorded state before it."""
        self._arm.update_initial_joints(initial_joints)
        hands = []
        for state, action in zip(states_before, actions, strict=True):
            self._load(state)
            hands.append(self._step(action))
        return np.array(hands)

    def open_loop(
        self, first_state: np.ndarray, actions: np.ndarray, initial_joints: np.ndarray
    ) -> np.ndarray:
        """Hand positions after each action, all stepped from the first state (action replay)."""
        self._arm.update_initial_joints(initial_joints)
        self._load(first_state)
        return np.array([self._step(action) for action in actions])
