"""A simulation driven by device commands: what a teleop session runs every control step."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
import numpy.typing as npt

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import ControlConfig
from crowdteleop.control.ik_velocity import IKVelocityController
from crowdteleop.control.mapping import ClutchMapper
from crowdteleop.control.osc import OSCController
from crowdteleop.errors import ConfigError
from crowdteleop.sim.interface import Simulation
from crowdteleop.sim.types import Pose, RobotState, StepResult
from crowdteleop.vocab import ActionMode


class ControlLaw(Protocol):
    """Turns a target end-effector pose into one simulation action (IK velocity or OSC)."""

    action_mode: ActionMode

    def reset(self) -> None: ...

    def action(
        self, target: Pose, gripper_closed: bool, robot: RobotState
    ) -> npt.NDArray[np.float64]: ...


def make_controller(config: ControlConfig, sim: Simulation) -> ControlLaw:
    if sim.action_spec.mode != config.action_mode:
        raise ConfigError(
            f"controller {config.controller!r} needs a simulation in action mode "
            f"{config.action_mode!r}, this one is {sim.action_spec.mode!r}"
        )
    if config.controller == "ik-velocity":
        return IKVelocityController(sim.kinematics(), kv=config.kv)
    return OSCController()


@dataclass(frozen=True)
class TeleopStep:
    """One control step as it happened: what was commanded, what was applied, what followed."""

    command: DeviceCommand
    target: Pose
    action: npt.NDArray[np.float64]
    result: StepResult


class Teleoperator:
    """Clutch mapping + controller + simulation. While the clutch is released the arm holds the
    pose it had when released."""

    def __init__(self, sim: Simulation, config: ControlConfig) -> None:
        self.sim = sim
        self.config = config
        self.mapper = ClutchMapper(config.mapping)
        self.controller = make_controller(config, sim)
        self._hold: Pose | None = None

    def reset(self, seed: int | None = None) -> None:
        self.sim.reset(seed)
        self.mapper.reset()
        self.controller.reset()
        self._hold = None

    def step(self, command: DeviceCommand) -> TeleopStep:
        robot = self.sim.robot_state()
        target = self.mapper.target(command, robot.end_effector)
        if target is None:
            if self._hold is None:
                self._hold = robot.end_effector
            target = self._hold
        else:
            self._hold = None
        action = self.controller.action(target, command.gripper_closed, robot)
        return TeleopStep(command, target, action, self.sim.step(action))
