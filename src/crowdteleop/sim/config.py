"""Typed configuration of one simulation, validated on construction."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator

from crowdteleop.tasks import PLATFORM_GRIPPERS, ROBOSUITE_DEFAULT_GRIPPER, get_task
from crowdteleop.vocab import ActionMode


class SimConfig(BaseModel):
    """Which task, on which robot, driven how, at what control rate."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    task: str = "lift"
    robot: str = Field("Sawyer", description="robosuite arm name: Sawyer, Panda, UR5e, IIWA, ...")
    action_mode: ActionMode = "joint-velocity"
    control_hz: float = Field(20.0, gt=0, le=500, description="control steps per simulated second")
    max_joint_speed: float = Field(1.5, gt=0, le=10, description="rad/s, joint-velocity mode")
    gripper_ramp: bool = Field(
        True,
        description="robosuite's finger command ramp (the gripper's speed per step, kept between "
        "steps), so recorded gripper actions act in plain robosuite as they did here; False "
        "commands the fingers directly, as recordings made before 2026-12-02 were simulated",
    )
    exclude_base_contacts: bool = Field(
        True,
        description="exclude contacts between an arm's first link and its static base, which "
        "MuJoCo's parent filter misses: on robosuite's Sawyer their friction holds joint 0 "
        "still, and the hand cannot reach Lift's cube. False keeps robosuite's own model "
        "exactly, as `robosuite.make(**env_args)` builds it (docs/dataset.md)",
    )
    gripper: str | None = Field(
        None,
        pattern=r"^[A-Za-z][A-Za-z0-9]*$",
        validate_default=True,
        description="robosuite gripper class on the arm (e.g. PandaGripper, Robotiq140Gripper); "
        "'default': robosuite's default for the robot; unset: the platform's choice, robosuite's "
        "default except where it cannot grasp (crowdteleop.tasks.PLATFORM_GRIPPERS)",
    )
    robosuite_step: bool = Field(
        False,
        description="step with robosuite's own env.step (its controller at every substep), "
        "whatever the task declares: ~6x slower than the fast path, and the physics plain "
        "robosuite runs, to nanometres (dataset generate --robosuite-step)",
    )
    model_seed: int = Field(
        0,
        ge=0,
        description="seeds the model's own randomization (e.g. Lift's cube size), so a "
        "recorded config rebuilds the very model its episodes were recorded on",
    )

    @classmethod
    def from_recorded(cls, recorded: Mapping[str, Any]) -> SimConfig:
        """The config a recording was made with: a key it lacks takes the value it had then."""
        return cls(**(RECORDED_BEFORE_KEY | dict(recorded)))

    @property
    def gripper_type(self) -> str | None:
        """robosuite's ``gripper_types`` for this arm; None: robosuite's default."""
        return None if self.gripper == ROBOSUITE_DEFAULT_GRIPPER else self.gripper

    @field_validator("gripper")
    @classmethod
    def _name_the_gripper(cls, gripper: str | None, info: ValidationInfo) -> str:
        """Unset becomes the platform's choice for the robot, so a recorded config names the
        gripper its episodes were recorded with, whatever the platform chooses later."""
        if gripper is not None:
            return gripper
        return PLATFORM_GRIPPERS.get(info.data.get("robot", ""), ROBOSUITE_DEFAULT_GRIPPER)

    @field_validator("task")
    @classmethod
    def _task_exists(cls, name: str) -> str:
        get_task(name)  # raises UnknownTaskError listing the known tasks
        return name


# Fields added after recordings began, with the behaviour recordings made before them had.
RECORDED_BEFORE_KEY: dict[str, Any] = {
    "gripper_ramp": False,
    "gripper": ROBOSUITE_DEFAULT_GRIPPER,
}
