"""A campaign names tasks and robots: every pair it hands out must build, or the campaign is
refused when it is read, before any worker joins."""

from __future__ import annotations

import pytest
from pydantic import ValidationError

from crowdteleop.coord.service.campaign import CampaignConfig


def test_a_campaign_takes_new_tasks_and_any_single_arm_robot():
    campaign = CampaignConfig(tasks=["stack", "pick-place-milk"], robots=["UR5e", "Kinova3"])
    assert campaign.assignment(1)[:2] == ("pick-place-milk", "Kinova3")


@pytest.mark.parametrize(
    ("tasks", "robots", "message"),
    [
        (["stack"], ["R2D2"], "'R2D2' is not a single-arm robosuite robot"),
        (["no-such-task"], ["Panda"], "unknown task(s) ['no-such-task']"),
    ],
)
def test_a_pair_that_cannot_build_is_refused_with_its_reason(tasks, robots, message):
    with pytest.raises(ValidationError) as refused:
        CampaignConfig(tasks=tasks, robots=robots)
    assert message in str(refused.value)


def test_a_robot_a_plug_in_task_does_not_take_is_refused(with_task_plugin):
    with pytest.raises(ValidationError, match="robot 'Jaco' does not fit task 'high-lift'"):
        CampaignConfig(tasks=["high-lift"], robots=["Jaco"])
    assert CampaignConfig(tasks=["high-lift", "lift"], robots=["IIWA", "Jaco"])
