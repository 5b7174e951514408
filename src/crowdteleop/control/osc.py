"""robosuite's OSC_POSE driven from an absolute target: the action is the delta to the target.

OSC_POSE (delta mode, base frame) moves its goal to current + action * scale each step, with
the scales of the simulation's OSC (`crowdteleop.provenance.controllers.OscPose`); we send the
clipped, scaled error to the target.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from crowdteleop.provenance.controllers import OscPose
from crowdteleop.sim.types import Pose, RobotState
from crowdteleop.vocab import ActionMode


class OSCController:
    """`gain` > 1 leads the goal past the target a little: OSC's goal is only partly reached
    within one control step, so a unit gain converges slowly at the end. `osc` is the
    simulation's OSC, whose scales turn metres and radians into actions."""

    action_mode: ActionMode = "osc-pose"

    def __init__(
        self, gain: float = 2.0, lead_time_s: float = 0.1, osc: OscPose | None = None
    ) -> None:
        self.gain = gain
        self.lead_time_s = lead_time_s
        osc = OscPose() if osc is None else osc
        self._position_scale_m = osc.position_scale_m
        self._rotation_scale_rad = osc.rotation_scale_rad

    def reset(self) -> None:
        """Stateless between steps: nothing to forget."""

    def action(
        self, target: Pose, gripper_closed: bool, robot: RobotState
    ) -> npt.NDArray[np.float64]:
        world_to_base = robot.base.rotation.inv()
        # Aim where the hand will be, not where it is: subtracting the distance it will still
        # travel (velocity * lead time) damps the overshoot of chasing a moving goal.
        lead = self.lead_time_s * robot.end_effector_velocity
        position_error = target.position - robot.end_effector.position - lead[:3]
        position_error = world_to_base.apply(position_error)
        rotation_error = (target.rotation * robot.end_effector.rotation.inv()).as_rotvec()
        rotation_error = world_to_base.apply(rotation_error - lead[3:])
        arm = np.concatenate(
            [position_error / self._position_scale_m, rotation_error / self._rotation_scale_rad]
        )
        return np.append(np.clip(self.gain * arm, -1.0, 1.0), 1.0 if gripper_closed else -1.0)
