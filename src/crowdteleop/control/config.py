"""Typed configuration of the teleoperation controllers."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, field_validator

from crowdteleop.vocab import ActionMode, ControllerName, action_mode_for


class MappingConfig(BaseModel):
    """How device motion becomes end-effector motion."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    translation_scale: float = Field(1.0, gt=0, le=10, description="robot metres per device metre")
    device_to_robot: tuple[float, float, float, float] = Field(
        (0.0, 0.0, 0.0, 1.0),
        description="rotation (x, y, z, w) taking device-frame vectors into the robot base frame",
    )
    follow_rotation: bool = True

    @field_validator("device_to_robot")
    @classmethod
    def _unit_quaternion(cls, value: tuple[float, ...]) -> tuple[float, ...]:
        norm = sum(v * v for v in value) ** 0.5
        if not 0.99 < norm < 1.01:
            raise ValueError(f"device_to_robot must be a unit quaternion, norm is {norm:.3f}")
        return value


class ControlConfig(BaseModel):
    """Which controller turns the desired end-effector pose into simulation actions."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    controller: ControllerName = "ik-velocity"
    kv: float = Field(10.0, gt=0, le=50, description="ik-velocity gain: qdot = -kv (q - q*), 1/s")
    mapping: MappingConfig = MappingConfig()

    @property
    def action_mode(self) -> ActionMode:
        return action_mode_for(self.controller)
