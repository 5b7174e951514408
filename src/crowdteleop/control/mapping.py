"""Clutch and frame mapping: device pose -> desired end-effector pose.

On every engage the device pose is re-anchored to the current end-effector pose, so a worker can
let go, move the phone somewhere comfortable and carry on (the paper's clutch).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import MappingConfig
from crowdteleop.sim.types import Pose


class ClutchMapper:
    def __init__(self, config: MappingConfig) -> None:
        self.config = config
        self._device_to_robot = Rotation.from_quat(config.device_to_robot)
        self._anchor_device: Pose | None = None
        self._anchor_robot: Pose | None = None

    @property
    def engaged(self) -> bool:
        return self._anchor_device is not None

    def reset(self) -> None:
        self._anchor_device = None
        self._anchor_robot = None

    def target(self, command: DeviceCommand, end_effector: Pose) -> Pose | None:
        """The desired end-effector pose, or None while the clutch is released."""
        if not command.engaged:
            self.reset()
            return None
        device = Pose(command.position, command.quaternion)
        if self._anchor_device is None:
            self._anchor_device, self._anchor_robot = device, end_effector
        assert self._anchor_robot is not None
        to_robot = self._device_to_robot
        moved = device.position - self._anchor_device.position
        position = self._anchor_robot.position + self.config.translation_scale * to_robot.apply(
            moved
        )
        rotation = self._anchor_robot.rotation
        if self.config.follow_rotation:
            turned = device.rotation * self._anchor_device.rotation.inv()  # in the device frame
            rotation = to_robot * turned * to_robot.inv() * rotation
        return Pose(position, rotation.as_quat())

    def device_pose_for(self, target: Pose) -> Pose:
        """The device pose that would command `target` under the current anchor (inverse map).

        Scripted operators use it to act through the same path as a person's phone.
        """
        if self._anchor_device is None or self._anchor_robot is None:
            raise RuntimeError("the clutch is not engaged: there is no anchor to invert")
        to_robot = self._device_to_robot
        offset = (target.position - self._anchor_robot.position) / self.config.translation_scale
        position = self._anchor_device.position + to_robot.inv().apply(offset)
        turned_robot = target.rotation * self._anchor_robot.rotation.inv()
        turned_device = to_robot.inv() * turned_robot * to_robot
        rotation = turned_device * self._anchor_device.rotation
        return Pose(np.asarray(position), rotation.as_quat())
