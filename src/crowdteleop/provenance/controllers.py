"""robosuite's controller configurations for our two action modes, typed.

The one place the OSC's output scales, gains and limits are written (`OscPose`). Live control
(`control.osc` scales its errors by them), the robosuite backend (``robosuite.make`` and the
fast path's gains), the recorded ``env_args`` and the dataset tools (``actions_abs`` and its
absolute config, replay in plain robosuite) all read them here, so a recorded action means
the same thing to each.

Field names and values are robosuite's own: `to_robosuite` is the dict robosuite takes and the
JSON a file stores, every key written (a null one too); a stored config parses back with
``model_validate``. Both controllers are stateless between control steps, which is what makes
``set_state`` exact: the next step depends only on the MuJoCo state and the action.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, model_serializer

from crowdteleop.vocab import ActionMode

# As written: a stored 150 reads back as 150 and 600.0 as 600.0, so a parsed config is written
# back byte for byte.
Number = int | float
Axes6 = tuple[Number, Number, Number, Number, Number, Number]
Interpolation = Literal["linear"] | None


class _RobosuiteConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    @model_serializer
    def _every_key(self) -> dict[str, Any]:
        """robosuite reads every key: none is left out, not even a null one."""
        return {name: getattr(self, name) for name in type(self).model_fields}

    def to_robosuite(self) -> dict[str, Any]:
        """The dict robosuite takes (and a file stores as JSON)."""
        return self.model_dump(mode="json")


class Gripper(_RobosuiteConfig):
    """robosuite's gripper controller: the finger command ramps toward the action's sign."""

    type: Literal["GRIP"] = "GRIP"


def _damping(kp: float, damping_ratio: float) -> float:
    """robosuite's derivative gain: critical damping times the ratio."""
    return 2.0 * math.sqrt(kp) * damping_ratio


class OscPose(_RobosuiteConfig):
    """robosuite's OSC_POSE as its teleop devices drive it. A delta action (dx, dy, dz, ax, ay,
    az) in [-1, 1] moves the hand's goal by up to 5 cm and 0.5 rad in the arm base's frame
    (`output_max` per unit of `input_max`); a task-space spring of stiffness `kp` (robosuite's
    default for Sawyer), critically damped, pulls the hand there. With ``input_type`` absolute
    the action is the goal itself (``actions_abs``)."""

    type: Literal["OSC_POSE"] = "OSC_POSE"
    input_max: Number = 1
    input_min: Number = -1
    output_max: Axes6 = (0.05, 0.05, 0.05, 0.5, 0.5, 0.5)
    output_min: Axes6 = (-0.05, -0.05, -0.05, -0.5, -0.5, -0.5)
    kp: Number = 150
    damping_ratio: Number = 1
    impedance_mode: Literal["fixed"] = "fixed"
    kp_limits: tuple[Number, Number] = (0, 300)
    damping_ratio_limits: tuple[Number, Number] = (0, 10)
    position_limits: list[list[Number]] | None = None
    orientation_limits: list[list[Number]] | None = None
    uncouple_pos_ori: bool = True
    input_type: Literal["delta", "absolute"] = "delta"
    input_ref_frame: Literal["base", "world"] = "base"
    interpolation: Interpolation = None
    ramp_ratio: Number = 0.2
    gripper: Gripper = Gripper()

    @property
    def position_scale_m(self) -> float:
        """How far one unit of action moves the hand's goal."""
        return self.output_max[0] / self.input_max

    @property
    def rotation_scale_rad(self) -> float:
        """How far one unit of action turns the hand's goal."""
        return self.output_max[3] / self.input_max

    @property
    def action_scale(self) -> tuple[float, ...]:
        """Per axis (x, y, z, ax, ay, az): metres or radians per unit of action."""
        return tuple(high / self.input_max for high in self.output_max)

    @property
    def kd(self) -> float:
        return _damping(self.kp, self.damping_ratio)

    def absolute(self) -> OscPose:
        """The same gains reading absolute goals in the arm base's frame (``actions_abs``),
        within robosuite's default bounds."""
        bounds = OscPose()
        return self.model_copy(
            update={
                "input_type": "absolute",
                "input_ref_frame": "base",
                "input_max": bounds.input_max,
                "input_min": bounds.input_min,
                "output_max": bounds.output_max,
                "output_min": bounds.output_min,
            }
        )


class JointPosition(_RobosuiteConfig):
    """robosuite's JOINT_POSITION servo in delta mode, scaled so an action is a joint velocity
    in rad/s held over one control period (goal = q + qdot * dt): `velocity_servo`. robosuite's
    own JOINT_VELOCITY controller keeps integral and derivative error between steps, so a
    restored state would not reproduce the next step."""

    type: Literal["JOINT_POSITION"] = "JOINT_POSITION"
    input_max: Number
    input_min: Number
    output_max: Number
    output_min: Number
    kp: Number
    damping_ratio: Number = 1
    impedance_mode: Literal["fixed"] = "fixed"
    kp_limits: tuple[Number, Number]
    damping_ratio_limits: tuple[Number, Number] = (0, 10)
    qpos_limits: list[list[Number]] | None = None
    input_type: Literal["delta"] = "delta"
    interpolation: Interpolation = None
    ramp_ratio: Number = 0.2
    gripper: Gripper = Gripper()

    @classmethod
    def velocity_servo(cls, max_speed: float, control_dt: float) -> JointPosition:
        """Joint velocities up to ``max_speed`` rad/s. The servo re-anchors its goal every
        control step, so its damping (kd = 2 sqrt(kp)) eats into the commanded speed unless
        kp * dt is comparable to kd: kp = 1.5 / dt^2 keeps about 60% of the commanded joint
        speed at any control rate (20 Hz: kp = 600)."""
        stiffness = 1.5 / control_dt**2
        return cls(
            input_max=max_speed,
            input_min=-max_speed,
            output_max=max_speed * control_dt,
            output_min=-max_speed * control_dt,
            kp=stiffness,
            kp_limits=(0, stiffness),
        )

    @property
    def action_scale(self) -> tuple[float, ...]:
        """Radians of joint goal per unit of action (rad/s): the control period, one value for
        every joint."""
        return (self.output_max / self.input_max,)

    @property
    def kd(self) -> float:
        return _damping(self.kp, self.damping_ratio)


ArmController = Annotated[OscPose | JointPosition, Field(discriminator="type")]
"""The arm's part controller, told apart by robosuite's ``type``."""
_ARM_CONTROLLER: TypeAdapter[ArmController] = TypeAdapter(ArmController)


def parse_arm_controller(config: Mapping[str, Any]) -> ArmController:
    """An arm controller from robosuite's dict as a file stores it; pydantic's
    ``ValidationError`` names what is not one of ours."""
    return _ARM_CONTROLLER.validate_python(config)


def arm_controller(
    action_mode: ActionMode, control_dt: float, max_joint_speed: float
) -> ArmController:
    """The arm controller a simulation in ``action_mode`` runs: robosuite's OSC_POSE exactly
    as its teleop devices use it, or the joint-velocity servo."""
    if action_mode == "osc-pose":
        return OscPose()
    return JointPosition.velocity_servo(max_joint_speed, control_dt)


class BodyParts(_RobosuiteConfig):
    right: ArmController


class CompositeController(_RobosuiteConfig):
    """robosuite's BASIC composite controller with our arm controller on the right arm: the
    ``controller_configs`` of ``robosuite.make``."""

    type: Literal["BASIC"] = "BASIC"
    body_parts: BodyParts

    @classmethod
    def of(cls, arm: ArmController) -> CompositeController:
        return cls(body_parts=BodyParts(right=arm))

    @property
    def arm(self) -> ArmController:
        return self.body_parts.right

    def absolute(self) -> CompositeController:
        """robosuite's OSC_POSE reading ``actions_abs`` (absolute goals, base frame), with the
        recorded OSC's gains, or robosuite's defaults for a joint controller's demos."""
        arm = self.arm
        osc = arm if isinstance(arm, OscPose) else OscPose(gripper=arm.gripper)
        return CompositeController.of(osc.absolute())
