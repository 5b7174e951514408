"""robosuite's Sawyer rubs its first link on its static base, and the contact's friction holds
joint 0 still. Our model excludes that contact by default; ``exclude_base_contacts=False`` keeps
robosuite's model exactly, as ``robosuite.make(**env_args)`` builds it."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from crowdteleop.sim import SimConfig, make_simulation

SIDEWAYS = np.array([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, -1.0])  # OSC: 5 cm a step to the left


def base_turn_rad(exclude: bool, robot: str = "Sawyer") -> tuple[float, str]:
    config = SimConfig(
        task="lift", robot=robot, action_mode="osc-pose", exclude_base_contacts=exclude
    )
    sim = make_simulation(config)
    try:
        sim.reset(0)
        start = sim.robot_state().joint_positions[0]
        for _ in range(20):
            sim.step(SIDEWAYS)
        return abs(float(sim.robot_state().joint_positions[0] - start)), sim.mjcf_xml()
    finally:
        sim.close()


def excludes(xml: str) -> set[tuple[str | None, str | None]]:
    found = ET.fromstring(xml).findall("./contact/exclude")
    return {(e.get("body1"), e.get("body2")) for e in found}


def test_by_default_sawyers_base_turns_and_the_saved_model_says_why():
    turned, xml = base_turn_rad(exclude=True)
    assert turned > 0.1
    assert ("robot0_right_arm_base_link", "robot0_right_l0") in excludes(xml)


def test_robosuites_own_model_is_kept_on_request_base_contact_and_all():
    import robosuite

    from crowdteleop.dataset.robosuite_replay import REPLAY_KWARGS

    turned, xml = base_turn_rad(exclude=False)
    assert turned < 0.02  # robosuite's behaviour: the contact's friction holds joint 0
    plain = robosuite.make("Lift", robots="Sawyer", **REPLAY_KWARGS)
    try:
        assert excludes(xml) == excludes(plain.sim.model.get_xml())
    finally:
        plain.close()


@pytest.mark.parametrize("exclude", [True, False])
def test_pandas_base_has_no_such_contact(exclude):
    turned, _ = base_turn_rad(exclude, robot="Panda")
    assert turned > 0.1


def test_a_recording_made_before_a_key_existed_gets_the_behaviour_it_had():
    before = SimConfig.from_recorded({"task": "lift", "action_mode": "osc-pose"})
    assert before.gripper_ramp is False  # no finger ramp then
    assert before.exclude_base_contacts is True
    now = SimConfig.from_recorded({"task": "lift", "gripper_ramp": True})
    assert now.gripper_ramp is True
