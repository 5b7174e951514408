"""Step recorded OSC_POSE actions in plain robosuite, to check they keep robosuite's meaning.

Plain robosuite here is robosuite's own environment with its default Sawyer controller
(OSC_POSE, Python at every substep), loaded the way robosuite's playback script loads a
demonstration: `reset_from_xml_string(model_file)`, then states.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import robosuite
from robosuite.controllers import load_composite_controller_config

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import ControlConfig
from crowdteleop.control.scripted import ScriptedOperator, run_episode
from crowdteleop.control.teleoperator import Teleoperator, TeleopStep
from crowdteleop.errors import ConfigError
from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.sim.robosuite_backend import RobosuiteSimulation
from crowdteleop.tasks import get_task


@dataclass(frozen=True)
class RecordedEpisode:
    """What replaying an OSC episode in robosuite needs, and where our hand went."""

    mjcf_xml: str
    nullspace_posture: npt.NDArray[np.float64]
    states_before: list[npt.NDArray[np.float64]]
    actions: npt.NDArray[np.float64]
    hands_after: npt.NDArray[np.float64]
    success: bool


def record_scripted_osc_episode(
    task: str, seed: int, time_limit_s: float = 30.0
) -> RecordedEpisode:
    """A scripted operator performs `task` through our fast path with the `osc` controller."""
    control = ControlConfig(controller="osc")
    sim = make_simulation(SimConfig(task=task, action_mode="osc-pose"))
    if not isinstance(sim, RobosuiteSimulation):  # only robosuite's OSC has a null-space posture
        sim.close()
        raise ConfigError(f"task {task!r} does not run on robosuite: nothing to replay there")
    teleop = Teleoperator(sim, control)
    before: list[npt.NDArray[np.float64]] = []
    actions, hands = [], []
    step_once = teleop.step

    def recorded_step(command: DeviceCommand) -> TeleopStep:
        before.append(sim.get_state())
        step = step_once(command)
        actions.append(step.action)
        hands.append(sim.robot_state().end_effector.position)
        return step

    teleop.step = recorded_step  # type: ignore[method-assign]  # record what each step did
    try:
        operator = ScriptedOperator(sim, control.mapping, seed=seed)
        result = run_episode(teleop, operator, seed, time_limit_s=time_limit_s)
        return RecordedEpisode(
            sim.mjcf_xml(),
            sim.nullspace_posture,
            before,
            np.array(actions),
            np.array(hands),
            result.success,
        )
    finally:
        sim.close()


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

    def _load(self, state: npt.NDArray[np.float64]) -> None:
        """Set a recorded state, and make robosuite's arm controller read it.

        robosuite's controllers cache the arm's pose and refresh it only when their
        ``new_update`` flag is set, which happens after they compute torques. A controller that
        has not run since it was built (or since `update_initial_joints`) keeps the pose from
        before the load for the first substep and takes it as the "achieved" pose the action's
        delta adds to, so the first action after a load pulls the hand toward the old pose:
        4.4 mm on the first step of an episode, with the arm at rest and a zero action.
        """
        self._env.sim.set_state_from_flattened(state)
        self._arm.update(force=True)  # runs the forward pass, then reads the arm

    def _step(self, action: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        # robosuite ramps its finger command 0.2 per step; start it where our (stateless) gripper
        # command is, so the comparison measures the arm.
        self._gripper.current_action = self._closed * action[-1] - (
            self._closed * self._gripper.speed * np.sign(action[-1])
        )
        self._env.step(action)
        return np.array(self._env.sim.data.site_xpos[self._site])

    def per_step(
        self,
        states_before: Sequence[npt.NDArray[np.float64]],
        actions: npt.NDArray[np.float64],
        initial_joints: npt.NDArray[np.float64],
    ) -> npt.NDArray[np.float64]:
        """Hand positions after each action, each stepped from the recorded state before it."""
        self._arm.update_initial_joints(initial_joints)
        hands = []
        for state, action in zip(states_before, actions, strict=True):
            self._load(state)
            hands.append(self._step(action))
        return np.array(hands)

    def open_loop(
        self,
        first_state: npt.NDArray[np.float64],
        actions: npt.NDArray[np.float64],
        initial_joints: npt.NDArray[np.float64],
    ) -> npt.NDArray[np.float64]:
        """Hand positions after each action, all stepped from the first state (action replay)."""
        self._arm.update_initial_joints(initial_joints)
        self._load(first_state)
        return np.array([self._step(action) for action in actions])


@dataclass(frozen=True)
class StatePlayback:
    """robosuite's playback of one demo: how far its states read back, and the last verdict."""

    steps: int
    max_state_error: float
    success_at_end: bool


def play_states_in_robosuite(dataset: str, demo: str) -> StatePlayback:
    """Replay a built dataset's demo the way robosuite's ``playback_demonstrations_from_hdf5``
    does: ``robosuite.make(env_name, **env_kwargs)``, ``reset_from_xml_string(model_file)``,
    then each state set with ``set_state_from_flattened`` and read back."""
    import json

    import h5py

    with h5py.File(dataset, "r") as file:
        env_args = json.loads(file["data"].attrs["env_args"])
        group = file["data"][demo]
        states = group["states"][()]
        model_file = str(group.attrs["model_file"])
    kwargs = dict(env_args.get("env_kwargs", {}))
    robots = kwargs.pop("robots", ["Sawyer"])
    env = robosuite.make(
        env_args["env_name"],
        robots=robots,
        has_renderer=False,
        has_offscreen_renderer=False,
        use_camera_obs=False,
        ignore_done=True,
        **kwargs,
    )
    try:
        env.reset()
        env.reset_from_xml_string(model_file)
        env.sim.reset()
        error = 0.0
        for state in states:
            env.sim.set_state_from_flattened(state)
            env.sim.forward()
            error = max(error, float(np.abs(env.sim.get_state().flatten() - state).max()))
        return StatePlayback(len(states), error, bool(env._check_success()))
    finally:
        env.close()
