"""The clutch's state machine (crowdteleop.teleop.clutch): every transition ends in a named
state the pages show, and from each the next press drives or the state says what is in the
way."""

from __future__ import annotations

import pytest

from crowdteleop.teleop.clutch import Clutch
from crowdteleop.vocab import CLUTCH_STATES


def driving() -> Clutch:
    clutch = Clutch()
    clutch.switch()
    clutch.device(held=True, has_pose=True)
    assert clutch.state == "driving" and clutch.engaged
    return clutch


def test_nobody_drives_until_a_device_takes_control_and_then_it_starts_let_go():
    clutch = Clutch()
    clutch.device(held=True, has_pose=True)
    assert clutch.state == "no_driver" and not clutch.engaged
    clutch.switch()
    assert clutch.state == "released"


def test_a_press_drives_and_letting_go_releases():
    clutch = driving()
    clutch.device(held=False, has_pose=True)
    assert clutch.state == "released" and not clutch.engaged


def test_a_press_before_any_pose_waits_for_one_then_drives():
    clutch = Clutch()
    clutch.switch()
    clutch.device(held=True, has_pose=False)
    assert clutch.state == "waiting_for_pose" and not clutch.engaged
    clutch.device(held=True, has_pose=True)
    assert clutch.state == "driving"


def test_a_stall_stops_the_arm_and_a_press_held_through_it_must_be_made_again():
    clutch = driving()
    clutch.stall(True)
    assert clutch.state == "video_stalled" and not clutch.engaged
    clutch.device(held=True, has_pose=True)
    assert clutch.state == "video_stalled", "nothing drives blind"
    clutch.stall(False)
    assert clutch.state == "press_again" and not clutch.engaged
    clutch.device(held=True, has_pose=True)
    assert clutch.state == "press_again", "the press from before the stall is an old one"
    clutch.device(held=False, has_pose=True)
    assert clutch.state == "released"
    clutch.device(held=True, has_pose=True)
    assert clutch.state == "driving", "let go and pressed again: the next press drives"


@pytest.mark.parametrize(("held_at_the_end", "then"), [(False, "released"), (True, "driving")])
def test_letting_go_during_a_stall_makes_the_next_press_a_fresh_one(held_at_the_end, then):
    clutch = driving()
    clutch.stall(True)
    clutch.device(held=False, has_pose=True)
    clutch.device(held=held_at_the_end, has_pose=True)
    clutch.stall(False)
    assert clutch.state == then


def test_a_device_switch_clears_an_old_press_so_the_new_devices_first_press_drives():
    """The issue's fault: after a stall the keyboard (its clutch on by default) never let go,
    and the phone that took over lit its button and nothing moved."""
    clutch = driving()
    clutch.stall(True)
    clutch.stall(False)
    assert clutch.state == "press_again"
    clutch.switch()
    assert clutch.state == "released"
    clutch.device(held=True, has_pose=True)
    assert clutch.state == "driving"


def test_a_switch_while_the_picture_is_frozen_waits_for_the_picture_not_for_a_new_press():
    clutch = driving()
    clutch.stall(True)
    clutch.switch()
    assert clutch.state == "video_stalled"
    clutch.device(held=True, has_pose=True)  # the new device pressed while frozen
    clutch.stall(False)
    assert clutch.state == "driving"


def test_a_scene_reset_stops_the_arm_until_the_devices_next_message():
    clutch = driving()
    clutch.scene_reset()
    assert clutch.state == "released" and not clutch.engaged
    clutch.device(held=True, has_pose=True)
    assert clutch.state == "driving"


def test_the_driver_leaving_ends_in_no_driver_and_a_stall_then_changes_nothing():
    clutch = driving()
    clutch.leave()
    assert clutch.state == "no_driver"
    clutch.stall(True)
    assert clutch.state == "no_driver"
    clutch.switch()
    assert clutch.state == "video_stalled"


def test_every_state_is_reachable():
    seen = set()
    clutch = Clutch()
    seen.add(clutch.state)
    clutch.switch()
    seen.add(clutch.state)
    clutch.device(held=True, has_pose=False)
    seen.add(clutch.state)
    clutch.device(held=True, has_pose=True)
    seen.add(clutch.state)
    clutch.stall(True)
    seen.add(clutch.state)
    clutch.stall(False)
    seen.add(clutch.state)
    assert seen == set(CLUTCH_STATES)
