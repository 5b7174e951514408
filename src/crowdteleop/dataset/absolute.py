"""``actions_abs``: each step's end-effector target as an absolute pose, robomimic's layout.

Delta actions compound when replayed open loop: every small difference between two simulators
moves the next delta's origin. An absolute target does not. Each row is
``[x, y, z, ax, ay, az, gripper]``: the hand's goal position and orientation (axis-angle) in the
frame of robosuite's arm base site (``robot0_right_center``), exactly what robosuite's OSC_POSE
takes with ``input_type="absolute"`` and ``input_ref_frame="base"``
(``CompositeController.absolute``), and what robosuite's own ``delta_to_abs_action`` computes.

- ``osc``: the goal the delta action set (current hand pose plus the scaled delta, in the base
  frame): stepping it in robosuite's absolute OSC is the same control law as the delta.
- ``ik-velocity``: the hand pose at the joint goal the step set (``q + qdot * dt``, forward
  kinematics on the recorded model).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import mujoco
import numpy as np
import numpy.typing as npt
from pydantic import ValidationError
from scipy.spatial.transform import Rotation

from crowdteleop.dataset.files import DatasetError
from crowdteleop.provenance.controllers import ArmController, OscPose, parse_arm_controller
from crowdteleop.sim.types import KinematicModel


def arm_of(config: ArmController | Mapping[str, Any]) -> ArmController:
    """The arm's controller, typed: as given, or parsed from robosuite's dict as a file holds it."""
    if isinstance(config, Mapping):
        try:
            return parse_arm_controller(config)
        except ValidationError as error:
            kind = config.get("type")
            raise DatasetError(f"no absolute targets for a {kind} controller: {error}") from error
    return config


class AbsoluteTargets:
    """Forward kinematics of one recorded model, for turning actions into absolute targets."""

    def __init__(
        self, kinematics: KinematicModel, arm_config: ArmController | Mapping[str, Any]
    ) -> None:
        self._model = mujoco.MjModel.from_xml_string(kinematics.mjcf_xml)
        self._data = mujoco.MjData(self._model)
        model = self._model
        joints = [model.joint(name).id for name in kinematics.arm_joints]
        self._arm_qpos = model.jnt_qposadr[joints]
        self._eef = model.site(kinematics.end_effector_site).id
        prefix = kinematics.arm_joints[0].split("_")[0] + "_"
        centre = [
            model.site(i).name
            for i in range(model.nsite)
            if model.site(i).name.startswith(prefix) and model.site(i).name.endswith("_center")
        ]
        if not centre:
            raise DatasetError("the recorded model has no arm base site (robot0_right_center)")
        self._centre = model.site(centre[0]).id
        arm = arm_of(arm_config)
        self._osc = isinstance(arm, OscPose)  # else the joint-velocity servo
        self._scale = np.asarray(arm.action_scale, dtype=float)

    def _frames(self, qpos: npt.NDArray[np.float64]) -> tuple[Any, Any, Any, Any]:
        data = self._data
        data.qpos[:] = qpos
        mujoco.mj_kinematics(self._model, data)
        return (
            data.site_xpos[self._eef].copy(),
            data.site_xmat[self._eef].reshape(3, 3).copy(),
            data.site_xpos[self._centre].copy(),
            data.site_xmat[self._centre].reshape(3, 3).copy(),
        )

    def base_frame(self, state: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
        """(4, 4) pose of the arm base's frame (the targets' frame) in the world, at ``state``."""
        _, _, base, base_rot = self._frames(state[1 : 1 + self._model.nq])
        frame = np.eye(4)
        frame[:3, :3], frame[:3, 3] = base_rot, base
        return frame

    def of(
        self, states: npt.NDArray[np.float64], actions: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
        """(N, 7) absolute targets for N (state before, action) pairs."""
        nq = self._model.nq
        rows = []
        for state, action in zip(states, actions, strict=True):
            qpos = state[1 : 1 + nq]
            hand, hand_rot, base, base_rot = self._frames(qpos)
            if self._osc:
                delta = action[:6] * np.broadcast_to(self._scale, (6,))
                goal = hand + base_rot @ delta[:3]
                turn = Rotation.from_rotvec(delta[3:]).as_matrix()
                goal_rot = base_rot @ turn @ base_rot.T @ hand_rot
            else:
                moved = qpos.copy()
                moved[self._arm_qpos] += action[:-1] * self._scale
                goal, goal_rot, _, _ = self._frames(moved)
            position = base_rot.T @ (goal - base)
            rotation = Rotation.from_matrix(base_rot.T @ goal_rot).as_rotvec()
            rows.append(np.concatenate([position, rotation, action[-1:]]))
        return np.array(rows, dtype=np.float64)

    def to_delta(
        self, state: npt.NDArray[np.float64], target: npt.NDArray[np.float64]
    ) -> npt.NDArray[np.float64]:
        """The OSC_POSE delta action that sets the same goal as absolute ``target`` from
        ``state``: how a policy trained on ``actions_abs`` drives an ``osc`` simulation (the
        same law as robosuite's absolute OSC while the goal is within one step's reach, the
        OSC's output scales; clipped beyond)."""
        if not self._osc:
            raise DatasetError("absolute targets turn into OSC_POSE deltas only")
        hand, hand_rot, base, base_rot = self._frames(state[1 : 1 + self._model.nq])
        goal = base + base_rot @ target[:3]
        goal_rot = base_rot @ Rotation.from_rotvec(target[3:6]).as_matrix()
        move = base_rot.T @ (goal - hand)
        turn = Rotation.from_matrix(base_rot.T @ goal_rot @ hand_rot.T @ base_rot).as_rotvec()
        delta = np.concatenate([move, turn]) / np.broadcast_to(self._scale, (6,))
        return np.concatenate([np.clip(delta, -1.0, 1.0), target[6:7]])
