"""The typed controller configurations (crowdteleop.provenance.controllers): robosuite's JSON
as files store it, and the one source of the OSC's scales for everything that reads them."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pydantic import ValidationError

from crowdteleop.provenance.controllers import (
    CompositeController,
    JointPosition,
    OscPose,
    arm_controller,
    parse_arm_controller,
)


def test_a_stored_config_reads_back_and_writes_back_byte_for_byte():
    for arm in (OscPose(), JointPosition.velocity_servo(1.5, 0.05)):
        text = json.dumps(CompositeController.of(arm).to_robosuite())
        parsed = CompositeController.model_validate_json(text)
        assert parsed.arm == arm
        assert json.dumps(parsed.to_robosuite()) == text


def test_every_key_is_written_null_ones_too():
    """robosuite reads position_limits and interpolation: a missing key is not a null one."""
    written = OscPose().to_robosuite()
    assert written["position_limits"] is None and written["interpolation"] is None
    assert written["output_max"] == [0.05, 0.05, 0.05, 0.5, 0.5, 0.5]
    assert written["gripper"] == {"type": "GRIP"}


def test_the_joint_servo_moves_its_goal_by_the_velocity_over_one_period():
    servo = arm_controller("joint-velocity", control_dt=0.05, max_joint_speed=1.5)
    assert isinstance(servo, JointPosition)
    assert servo.action_scale == pytest.approx((0.05,))  # rad of goal per rad/s of action
    assert servo.kp == pytest.approx(600.0) and servo.kd == pytest.approx(2 * np.sqrt(600.0))


def test_absolute_keeps_the_recorded_gains_and_reads_goals():
    recorded = CompositeController.of(OscPose(kp=200))
    absolute = recorded.absolute().arm
    assert isinstance(absolute, OscPose)
    assert (absolute.input_type, absolute.input_ref_frame, absolute.kp) == ("absolute", "base", 200)
    after_joints = CompositeController.of(JointPosition.velocity_servo(1.5, 0.05)).absolute().arm
    assert after_joints == OscPose(input_type="absolute")


def test_a_controller_we_do_not_run_is_named_when_refused():
    with pytest.raises(ValidationError, match="JOINT_VELOCITY"):
        parse_arm_controller({"type": "JOINT_VELOCITY", "kp": 1})


def test_live_control_scales_by_the_same_osc():
    """A target one OSC step away (output_max per unit) is one unit of action."""
    from crowdteleop.control.osc import OSCController
    from crowdteleop.sim.types import Pose, RobotState

    osc = OscPose()
    identity = np.array([0.0, 0.0, 0.0, 1.0])
    hand = Pose(np.zeros(3), identity)
    robot = RobotState(np.zeros(7), np.zeros(7), hand, Pose(np.zeros(3), identity), 0.0)
    target = Pose(np.array([osc.position_scale_m, 0.0, 0.0]), identity)
    action = OSCController(gain=1.0, lead_time_s=0.0).action(target, False, robot)
    np.testing.assert_allclose(action, [1.0, 0, 0, 0, 0, 0, -1.0], atol=1e-12)
