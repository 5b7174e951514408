"""Clutch and frame mapping: device pose -> desired end-effector pose.

On every engage the device pose is re-anchored to the current end-effector pose, so a worker can
let go, move the phone somewhere comfortable and carry on (the paper's clutch).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import MappingConfig
from crowdteleop.sim.types import Pose

Quaternion = tuple[float, float, float, float]  # (x, y, z, w)


def _unit(q: npt.NDArray[np.float64] | tuple[float, ...]) -> Quaternion:
    x, y, z, w = (float(v) for v in q)
    norm = (x * x + y * y + z * z + w * w) ** 0.5
    return x / norm, y / norm, z / norm, w / norm


def _mul(a: Quaternion, b: Quaternion) -> Quaternion:
    """Hamilton product: the rotation b, then a (scipy's ``Rotation(a) * Rotation(b)``)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def _inv(q: Quaternion) -> Quaternion:
    return -q[0], -q[1], -q[2], q[3]


def _rotate(q: Quaternion, v: npt.NDArray[np.float64]) -> npt.NDArray[np.float64]:
    x, y, z, _ = _mul(_mul(q, (float(v[0]), float(v[1]), float(v[2]), 0.0)), _inv(q))
    return np.array([x, y, z])


class ClutchMapper:
    """Device pose -> end-effector target, re-anchored on every engage.

    Runs every control step of every session, so quaternions are composed with plain float
    arithmetic (the same Hamilton products, same signs, as scipy's `Rotation`): scipy took
    ~0.5-0.8 ms per step here, most of it array-API dispatch around four multiplications.
    """

    def __init__(self, config: MappingConfig) -> None:
        self.config = config
        self._device_to_robot = _unit(config.device_to_robot)
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
        device = Pose(np.asarray(command.position, dtype=float), command.quaternion)
        if self._anchor_device is None:
            self._anchor_device, self._anchor_robot = device, end_effector
        assert self._anchor_robot is not None
        to_robot = self._device_to_robot
        moved = device.position - self._anchor_device.position
        position = self._anchor_robot.position + self.config.translation_scale * _rotate(
            to_robot, moved
        )
        rotation = _unit(self._anchor_robot.quaternion)
        if self.config.follow_rotation:
            # turned in the device frame, expressed in the robot frame, applied to the anchor
            turned = _mul(_unit(device.quaternion), _inv(_unit(self._anchor_device.quaternion)))
            rotation = _mul(_mul(_mul(to_robot, turned), _inv(to_robot)), rotation)
        return Pose(position, np.array(rotation))

    def device_pose_for(self, target: Pose) -> Pose:
        """The device pose that would command `target` under the current anchor (inverse map).

        Scripted operators use it to act through the same path as a person's phone.
        """
        if self._anchor_device is None or self._anchor_robot is None:
            raise RuntimeError("the clutch is not engaged: there is no anchor to invert")
        to_robot = self._device_to_robot
        offset = (target.position - self._anchor_robot.position) / self.config.translation_scale
        position = self._anchor_device.position + _rotate(_inv(to_robot), offset)
        turned_robot = _mul(_unit(target.quaternion), _inv(_unit(self._anchor_robot.quaternion)))
        turned_device = _mul(_mul(_inv(to_robot), turned_robot), to_robot)
        rotation = _mul(turned_device, _unit(self._anchor_device.quaternion))
        return Pose(np.asarray(position), np.array(rotation))
