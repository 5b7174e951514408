"""The command board (crowdteleop.teleop.commands): latest pose wins, clutch events are never
undone by late poses, one device drives at a time."""

from __future__ import annotations

import numpy as np
import pytest

from crowdteleop.control.config import ControlConfig
from crowdteleop.control.teleoperator import Teleoperator
from crowdteleop.teleop.commands import CommandBoard, NotInControlError
from crowdteleop.teleop.protocol import ClutchEvent
from tests.fixtures.poses import pose as _pose


def test_latest_pose_wins_and_stale_ones_are_dropped():
    board = CommandBoard()
    assert board.apply_pose("p1", _pose(5))
    assert not board.apply_pose("p1", _pose(3)), "an older pose arriving late is stale"
    assert board.command().seq == 5


def test_a_late_pose_cannot_undo_a_newer_clutch_release():
    board = CommandBoard()
    board.apply_pose("p1", _pose(1))
    release = ClutchEvent(seq=3, client_time_ms=0.0, device="phone", engaged=False)
    board.apply_event("p1", release)
    board.apply_pose("p1", _pose(2, engaged=True))
    assert not board.command().engaged


def test_only_the_controlling_device_drives_until_it_hands_over():
    board = CommandBoard()
    board.apply_pose("browser", _pose(1, device="keyboard"))
    with pytest.raises(NotInControlError):
        board.apply_pose("phone", _pose(1, device="phone"))
    assert board.take_control("phone", "phone")
    assert not board.command().engaged, "a new device starts with the clutch released"
    assert board.apply_pose("phone", _pose(1, device="phone"))
    assert board.release("phone") and board.driver is None


def test_a_device_taking_over_mid_press_anchors_where_the_hand_is(lift_sim):
    """Control passes between two engaged devices (a second tab takes over a first whose clutch
    is held) between two control steps: the arm stays where it is, it does not jump to where the
    old device's anchor would put the new device's pose."""
    board, teleop = CommandBoard(), Teleoperator(lift_sim, ControlConfig())
    teleop.reset(0)
    board.apply_pose("tab-1", _pose(1, device="keyboard", position=(0.0, 0.0, 0.0)))
    teleop.step(board.command())
    board.apply_pose("tab-1", _pose(2, device="keyboard", position=(0.1, 0.0, 0.0)))
    for _ in range(30):  # the hand follows the first tab 10 cm
        teleop.step(board.command())
    hand = lift_sim.robot_state().end_effector.position

    board.take_control("tab-2", "keyboard")  # both before the next control step
    board.apply_pose("tab-2", _pose(1, device="keyboard", position=(0.0, 0.0, 0.0)))
    for _ in range(30):
        teleop.step(board.command())

    assert np.linalg.norm(lift_sim.robot_state().end_effector.position - hand) < 0.01


def test_a_video_stall_holds_the_clutch_open_until_the_device_lets_go_and_presses_again():
    board = CommandBoard()
    board.apply_pose("p", _pose(1, engaged=True))
    board.command()  # the first step after taking control shows the clutch released
    assert board.command().engaged
    assert board.set_video_stalled(True)
    assert not board.command().engaged, "the stall releases the clutch at once"
    board.apply_pose("p", _pose(2, engaged=True))
    assert not board.command().engaged, "a held button does not drive blind"
    board.set_video_stalled(False)
    board.apply_pose("p", _pose(3, engaged=True))
    assert not board.command().engaged, "the picture is back, but the press is an old one"
    board.apply_pose("p", _pose(4, engaged=False))
    board.apply_pose("p", _pose(5, engaged=True))
    assert board.command().engaged, "let go and pressed again: drives"


def test_letting_go_during_a_stall_counts_as_the_release():
    board = CommandBoard()
    board.set_video_stalled(True)
    board.apply_pose("p", _pose(1, engaged=False))
    board.command()
    board.apply_pose("p", _pose(2, engaged=True))
    assert not board.command().engaged, "never while the video is stalled"
    board.set_video_stalled(False)
    board.apply_pose("p", _pose(3, engaged=True))
    assert board.command().engaged


def test_a_device_taking_over_after_a_stall_drives_with_its_first_press():
    """A keyboard (its clutch on by default) drove through a stall and never let go; the phone
    that takes over presses once and drives."""
    board = CommandBoard()
    board.apply_pose("tab", _pose(1, device="keyboard", engaged=True))
    board.command()
    board.set_video_stalled(True)
    board.apply_pose("tab", _pose(2, device="keyboard", engaged=True))
    board.set_video_stalled(False)
    assert board.clutch.state == "press_again"
    board.take_control("handset", "phone")
    assert board.clutch.state == "released"
    board.apply_event(
        "handset", ClutchEvent(device="phone", seq=1, client_time_ms=1.0, engaged=True)
    )
    assert board.clutch.state == "waiting_for_pose", "a press before any pose waits for one"
    board.apply_pose("handset", _pose(2, device="phone", engaged=True))
    board.command()  # the step that shows the hand-over's release
    assert board.command().engaged and board.clutch.state == "driving"
