"""Step recorded actions in plain robosuite, to check they keep robosuite's meaning.

Plain robosuite here is robosuite's own environment, rebuilt from what a dataset records
(``env_name`` and ``env_kwargs``: robot, controller config, control rate) and loaded the way
robosuite's playback script loads a demonstration: `reset_from_xml_string(model_file)`, then
states. Its controllers run in Python at every substep; ours are linearized once per step.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import robosuite

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import ControlConfig
from crowdteleop.control.scripted import ScriptedOperator, run_episode
from crowdteleop.control.teleoperator import Teleoperator, TeleopStep
from crowdteleop.errors import ConfigError
from crowdteleop.provenance.env_args import EnvArgs
from crowdteleop.recording.metadata import robosuite_version
from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.sim.robosuite_backend import RobosuiteSimulation
from crowdteleop.tasks import get_task, import_env_module, task_names
from crowdteleop.vocab import ControllerName

# What replaying needs and robosuite.make would otherwise default differently.
REPLAY_KWARGS = {
    "has_renderer": False,
    "has_offscreen_renderer": False,
    "use_camera_obs": False,
    "ignore_done": True,
}


@dataclass(frozen=True)
class RecordedEpisode:
    """What replaying an episode in robosuite needs, and where our hand and fingers went."""

    task: str
    env_args: EnvArgs
    mjcf_xml: str
    nullspace_posture: npt.NDArray[np.float64]
    states_before: list[npt.NDArray[np.float64]]
    finger_commands: npt.NDArray[np.float64]  # (N,): robosuite's ramped command before each step
    actions: npt.NDArray[np.float64]
    hands_after: npt.NDArray[np.float64]
    fingers_after: npt.NDArray[np.float64]  # (N, 2) finger joint positions
    success: bool


def record_scripted_episode_in_memory(
    task: str, seed: int, controller: ControllerName = "osc", time_limit_s: float = 30.0
) -> RecordedEpisode:
    """A scripted operator performs `task` through our fast path with `controller`."""
    control = ControlConfig(controller=controller)
    config = SimConfig(task=task, action_mode=control.action_mode)
    sim = make_simulation(config)
    if not isinstance(sim, RobosuiteSimulation):
        sim.close()
        raise ConfigError(f"task {task!r} does not run on robosuite: nothing to replay there")
    teleop = Teleoperator(sim, control)
    before: list[npt.NDArray[np.float64]] = []
    commands, actions, hands, fingers = [], [], [], []
    step_once = teleop.step

    def recorded_step(command: DeviceCommand) -> TeleopStep:
        before.append(sim.get_state())
        commands.append(float(sim.controller_state()[0]))
        step = step_once(command)
        actions.append(step.action)
        hands.append(sim.robot_state().end_effector.position)
        fingers.append(sim.observations()["robot0_gripper_qpos"])
        return step

    teleop.step = recorded_step  # type: ignore[method-assign]  # record what each step did
    try:
        operator = ScriptedOperator(sim, control.mapping, seed=seed)
        result = run_episode(teleop, operator, seed, time_limit_s=time_limit_s)
        return RecordedEpisode(
            task,
            EnvArgs.of(config, robosuite_version()),
            sim.mjcf_xml(),
            sim.nullspace_posture,
            before,
            np.array(commands),
            np.array(actions),
            np.array(hands),
            np.array(fingers),
            result.success,
        )
    finally:
        sim.close()


@dataclass(frozen=True)
class Trajectory:
    """Where plain robosuite took the hand and fingers, step by step."""

    hands: npt.NDArray[np.float64]  # (N, 3)
    fingers: npt.NDArray[np.float64]  # (N, 2) finger joint positions
    finger_force_n: npt.NDArray[np.float64]  # (N,) finger actuator force, summed magnitude


class RobosuiteReplayer:
    """A plain robosuite environment rebuilt from ``env_args`` for one model."""

    def __init__(self, env_args: EnvArgs, mjcf_xml: str) -> None:
        kwargs = env_args.robosuite_kwargs(**REPLAY_KWARGS, hard_reset=False)
        self._env = robosuite.make(env_args.env_name, **kwargs)
        self._env.reset_from_xml_string(mjcf_xml)
        robot = self._env.robots[0]
        self._arm = robot.composite_controller.part_controllers[robot.arms[0]]
        self._gripper: Any = robot.gripper[robot.arms[0]]
        self._gripper.current_action = np.zeros_like(self._gripper.current_action)
        self._closed = np.sign(self._gripper.format_action(np.array([1.0])))
        self._site = self._env.sim.model.site_name2id(self._gripper.important_sites["grip_site"])
        joints = [self._env.sim.model.joint_name2id(j) for j in self._gripper.joints]
        self._finger_qpos = self._env.sim.model.jnt_qposadr[joints]
        self._finger_actuators = np.array(
            robot._ref_joint_gripper_actuator_indexes[robot.arms[0]], dtype=int
        )

    @classmethod
    def for_task(cls, task: str, controller: ControllerName, mjcf_xml: str) -> RobosuiteReplayer:
        control = ControlConfig(controller=controller)
        config = SimConfig(task=task, action_mode=control.action_mode)
        return cls(EnvArgs.of(config, robosuite_version()), mjcf_xml)

    @property
    def env(self) -> Any:
        """The plain robosuite environment (e.g. to time its step, or render its picture)."""
        return self._env

    def close(self) -> None:
        self._env.close()

    def _load(self, state: npt.NDArray[np.float64], finger_command: float) -> None:
        """Set a recorded state and finger command, and make robosuite's arm controller read it.

        robosuite's controllers cache the arm's pose and refresh it only when their
        ``new_update`` flag is set, which happens after they compute torques. A controller that
        has not run since it was built (or since `update_initial_joints`) keeps the pose from
        before the load for the first substep and takes it as the "achieved" pose the action's
        delta adds to, so the first action after a load pulls the hand toward the old pose:
        4.4 mm on the first step of an episode, with the arm at rest and a zero action.
        """
        self._env.sim.set_state_from_flattened(state)
        self._arm.update(force=True)  # runs the forward pass, then reads the arm
        self._gripper.current_action = self._closed * finger_command

    def _step(self, action: npt.NDArray[np.float64]) -> tuple[Any, Any, float]:
        self._env.step(action)
        data = self._env.sim.data
        force = float(np.abs(data.actuator_force[self._finger_actuators]).sum())
        return np.array(data.site_xpos[self._site]), np.array(data.qpos[self._finger_qpos]), force

    def _trajectory(self, steps: list[tuple[Any, Any, float]]) -> Trajectory:
        hands, fingers, forces = zip(*steps, strict=True)
        return Trajectory(np.array(hands), np.array(fingers), np.array(forces))

    def per_step(
        self,
        states_before: Sequence[npt.NDArray[np.float64]],
        actions: npt.NDArray[np.float64],
        initial_joints: npt.NDArray[np.float64],
        finger_commands: Sequence[float] | None = None,
    ) -> Trajectory:
        """Each action stepped from the recorded state (and finger command) before it."""
        self._arm.update_initial_joints(initial_joints)
        commands = finger_commands if finger_commands is not None else [0.0] * len(actions)
        steps = []
        for state, command, action in zip(states_before, commands, actions, strict=True):
            self._load(state, command)
            steps.append(self._step(action))
        return self._trajectory(steps)

    def open_loop(
        self,
        first_state: npt.NDArray[np.float64],
        actions: npt.NDArray[np.float64],
        initial_joints: npt.NDArray[np.float64] | None,
        first_finger_command: float = 0.0,
    ) -> Trajectory:
        """All actions stepped from the first state: robosuite's ``--use-actions`` playback
        (``initial_joints`` None: the OSC's null space pulls toward the first state's arm)."""
        self._load(first_state, first_finger_command)
        if initial_joints is None:
            initial_joints = np.array(self._env.robots[0]._joint_positions)
        self._arm.update_initial_joints(initial_joints)
        self._load(first_state, first_finger_command)
        return self._trajectory([self._step(action) for action in actions])


def register_task_env(task: str) -> None:
    """Make robosuite know a recorded task's environment class: a plug-in task's is defined
    in its own module (`TaskSpec.env_module`), which nothing may have imported yet. A task the
    catalogue does not know is left to robosuite.make to name."""
    if task in task_names():
        import_env_module(get_task(task))


@dataclass(frozen=True)
class StatePlayback:
    """robosuite's playback of one demo: how far its states read back, and the last verdict."""

    steps: int
    max_state_error: float
    success_at_end: bool


def play_states_in_robosuite(dataset: str, demo: str) -> StatePlayback:
    """Replay a built dataset's demo exactly as robosuite's
    ``scripts/playback_demonstrations_from_hdf5.py`` does: ``robosuite.make(**env_info, ...)``
    with the script's own arguments, ``reset_from_xml_string(edit_model_xml(model_file))``,
    ``sim.reset()``, then each state set with ``set_state_from_flattened`` and read back."""
    import h5py

    with h5py.File(dataset, "r") as file:
        env_info = json.loads(file["data"].attrs["env_info"])
        group = file["data"][demo]
        states = group["states"][()]
        model_file = str(group.attrs["model_file"])
        register_task_env(str(group.attrs.get("task", "")))
    env = robosuite.make(
        **env_info,
        has_renderer=False,  # the script opens a window; the rest is its arguments verbatim
        has_offscreen_renderer=False,
        ignore_done=True,
        use_camera_obs=False,
        reward_shaping=True,
        control_freq=20,
    )
    try:
        env.reset()
        env.reset_from_xml_string(env.edit_model_xml(model_file))
        env.sim.reset()
        error = 0.0
        for state in states:
            env.sim.set_state_from_flattened(state)
            env.sim.forward()
            error = max(error, float(np.abs(env.sim.get_state().flatten() - state).max()))
        return StatePlayback(len(states), error, bool(env._check_success()))
    finally:
        env.close()
