"""Device pose -> end-effector target: clutch re-anchoring, scale and frame mapping."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import MappingConfig
from crowdteleop.control.mapping import ClutchMapper
from crowdteleop.sim.types import Pose

HAND = Pose(np.array([0.5, 0.0, 1.0]), Rotation.from_euler("x", 180, degrees=True).as_quat())


NO_TURN = Rotation.identity()


def device(position, rotation=NO_TURN, engaged=True):
    return DeviceCommand(
        position=np.array(position, float), quaternion=rotation.as_quat(), engaged=engaged
    )


def test_engaging_anchors_the_device_to_the_current_hand_pose():
    mapper = ClutchMapper(MappingConfig())
    target = mapper.target(
        device([3.0, 2.0, 1.0], Rotation.from_euler("z", 40, degrees=True)), HAND
    )
    assert np.allclose(target.position, HAND.position)
    assert np.allclose(np.abs(target.quaternion @ HAND.quaternion), 1.0)


def test_device_motion_is_scaled_and_rotated_into_the_robot_frame():
    to_robot = Rotation.from_euler("z", 90, degrees=True)  # device x -> robot y
    mapper = ClutchMapper(MappingConfig(translation_scale=2.0, device_to_robot=to_robot.as_quat()))
    mapper.target(device([0, 0, 0]), HAND)
    target = mapper.target(device([0.1, 0, 0]), HAND)
    assert np.allclose(target.position - HAND.position, [0.0, 0.2, 0.0])


def test_releasing_the_clutch_lets_the_worker_reposition_the_phone_without_a_jump():
    mapper = ClutchMapper(MappingConfig())
    mapper.target(device([0, 0, 0]), HAND)
    moved = mapper.target(device([0.1, 0, 0]), HAND)
    assert mapper.target(device([5, 5, 5], engaged=False), HAND) is None
    assert not mapper.engaged
    hand_now = Pose(moved.position, moved.quaternion)
    re_engaged = mapper.target(device([5, 5, 5]), hand_now)
    assert np.allclose(re_engaged.position, hand_now.position)
    further = mapper.target(device([5, 5, 5.05]), hand_now)
    assert np.allclose(further.position - hand_now.position, [0, 0, 0.05])


def test_device_rotation_turns_the_hand_about_the_mapped_axis():
    mapper = ClutchMapper(MappingConfig())
    mapper.target(device([0, 0, 0]), HAND)
    turned = mapper.target(device([0, 0, 0], Rotation.from_euler("z", 30, degrees=True)), HAND)
    relative = Pose(turned.position, turned.quaternion).rotation * HAND.rotation.inv()
    assert np.allclose(relative.as_rotvec(), [0, 0, np.radians(30)], atol=1e-9)


def test_rotation_can_be_ignored():
    mapper = ClutchMapper(MappingConfig(follow_rotation=False))
    mapper.target(device([0, 0, 0]), HAND)
    turned = mapper.target(device([0, 0, 0], Rotation.from_euler("y", 50, degrees=True)), HAND)
    assert np.allclose(np.abs(turned.quaternion @ HAND.quaternion), 1.0)


@pytest.mark.parametrize("scale", [0.5, 1.0, 3.0])
def test_device_pose_for_inverts_the_mapping(scale):
    to_robot = Rotation.from_euler("xyz", [10, -20, 75], degrees=True)
    mapper = ClutchMapper(
        MappingConfig(translation_scale=scale, device_to_robot=to_robot.as_quat())
    )
    mapper.target(device([0.3, 0.1, -0.2], Rotation.from_euler("y", 12, degrees=True)), HAND)
    command = device([0.4, -0.1, 0.0], Rotation.from_euler("xz", [20, -35], degrees=True))
    target = mapper.target(command, HAND)
    recovered = mapper.device_pose_for(target)
    assert np.allclose(recovered.position, command.position)
    assert np.allclose(np.abs(recovered.quaternion @ command.quaternion), 1.0)


def test_device_to_robot_must_be_a_unit_quaternion():
    with pytest.raises(ValueError, match="unit quaternion"):
        MappingConfig(device_to_robot=(0.0, 0.0, 0.0, 2.0))
