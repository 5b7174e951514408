"""Scripted operators, the platform's test users, complete the paper's tasks through the same
device commands a person would send (clutch, pose, gripper)."""

from __future__ import annotations

import numpy as np
import pytest

from crowdteleop.control.config import ControlConfig
from crowdteleop.control.scripted import OperatorStyle, ScriptedOperator, run_episode
from crowdteleop.control.teleoperator import Teleoperator
from crowdteleop.errors import ConfigError
from crowdteleop.sim import SimConfig, make_simulation

SEEDS = range(20)
REQUIRED_SUCCESS = {"lift": 0.95, "pick-place-can": 0.80, "nut-assembly-round": 0.80}
HUMAN_LIKE = OperatorStyle(
    speed_m_s=0.2, tremor_m=0.003, hesitation_probability=0.3, hesitation_s=(0.2, 1.0)
)


def success_rate(
    task: str,
    controller: str,
    seeds,
    style: OperatorStyle | None = None,
    robot: str = "Sawyer",
) -> float:
    control = ControlConfig(controller=controller)
    sim = make_simulation(SimConfig(task=task, action_mode=control.action_mode, robot=robot))
    try:
        teleop = Teleoperator(sim, control)
        operator = ScriptedOperator(sim, control.mapping, style=style, seed=1234)
        results = [run_episode(teleop, operator, seed, time_limit_s=45.0) for seed in seeds]
    finally:
        sim.close()
    return float(np.mean([result.success for result in results]))


@pytest.mark.slow
@pytest.mark.parametrize("task", list(REQUIRED_SUCCESS))
def test_success_rate_over_20_seeds_with_the_papers_controller(task):
    assert success_rate(task, "ik-velocity", SEEDS) >= REQUIRED_SUCCESS[task]


@pytest.mark.slow
@pytest.mark.parametrize("task", list(REQUIRED_SUCCESS))
def test_human_like_operators_still_succeed(task):
    """Tremor, hesitation and a slower hand: what later issues use as noisy test users."""
    assert success_rate(task, "ik-velocity", range(100, 106), HUMAN_LIKE) >= 0.8


@pytest.mark.slow
@pytest.mark.parametrize("task", ["lift", "nut-assembly-round"])
def test_operators_also_succeed_through_robosuite_osc(task):
    assert success_rate(task, "osc", range(200, 205)) >= 0.8


@pytest.mark.slow
@pytest.mark.parametrize("task", ["lift", "pick-place-can"])
def test_operators_succeed_on_robosuites_default_arm_too(task):
    """Panda (robosuite's and robomimic's arm for these tasks) reaches less far than Sawyer:
    the plan drops the can on the near side of its bin quadrant. (Measured over seeds 0-53:
    pick-place-can 50 / 54; the misses are cans in the source bin's far corners.)"""
    assert success_rate(task, "osc", range(10, 20), robot="Panda") >= 0.8


# Panda, osc, success over seeds 0-7 when measured: milk 8/8, bread 6/8, cereal 6/8 (a
# turned box may slip), square nut 5/8, stack 5/5 (seeds 0-4).
ROBOSUITE_TASKS_SUCCESS = {
    "pick-place-milk": 0.8,
    "pick-place-bread": 0.6,
    "pick-place-cereal": 0.6,
    "nut-assembly-square": 0.4,
    "stack": 0.8,
}


@pytest.mark.slow
@pytest.mark.parametrize("task", list(ROBOSUITE_TASKS_SUCCESS))
def test_operators_complete_the_other_robosuite_tasks(task):
    assert success_rate(task, "osc", range(5), robot="Panda") >= ROBOSUITE_TASKS_SUCCESS[task]


@pytest.mark.slow
@pytest.mark.parametrize(
    ("robot", "controller"),
    [("IIWA", "osc"), ("UR5e", "osc"), ("Kinova3", "ik-velocity"), ("Jaco", "ik-velocity")],
)
def test_lift_on_the_other_arms(robot, controller):
    """3 / 3 each, on the platform's grippers (`PLATFORM_GRIPPERS`): with robosuite's own,
    UR5e and Kinova3 (Robotiq85, robosuite#772) and Jaco (three fingers, 0.3 N) lift 0 / 3.
    Jaco through the OSC also 0 / 3: left for now (docs/tasks.md)."""
    assert success_rate("lift", controller, range(3), robot=robot) == 1.0


def test_the_second_backend_is_driven_by_the_same_operator_and_controller():
    assert success_rate("mujoco-lift", "ik-velocity", range(5)) == 1.0


def test_grasping_buzzes_haptics_and_advances_the_progress_stage():
    control = ControlConfig()
    sim = make_simulation(SimConfig(task="lift"))
    try:
        teleop, operator = Teleoperator(sim, control), ScriptedOperator(sim, seed=0)
        stages, finger_contacts = [], []
        teleop.reset(0)
        operator.reset()
        for _ in range(200):
            result = teleop.step(operator.command()).result
            stages.append(result.progress.stage)
            finger_contacts += [c for c in result.contacts if c.object == "cube"]
            if result.success:
                break
    finally:
        sim.close()
    assert stages[0] == "reach" and "grasped" in stages and stages[-1] == "done"
    assert {c.robot_part for c in finger_contacts} == {"right_l_finger_tip", "right_r_finger_tip"}
    assert all(0.0 < c.intensity <= 1.0 for c in finger_contacts)
    assert max(c.intensity for c in finger_contacts) > 0.05


def test_tasks_without_a_script_say_so():
    sim = make_simulation(SimConfig(task="pick-place"))
    try:
        with pytest.raises(ConfigError, match="no scripted operator for task 'pick-place'"):
            ScriptedOperator(sim)
    finally:
        sim.close()


@pytest.mark.parametrize("seed", [0, 3, 6])
def test_a_pick_place_grasp_closes_where_the_floor_holds_the_hand_up(seed):
    """The fingers meet the bin's floor short of the descent's mark under the can: the
    operator closes there within a second, instead of waiting out the leg's 6 s timeout (which
    put ~110 steps of an open hand at the can in every pick-place-can demonstration; seeds
    0, 3 and 6 waited so, before)."""
    control = ControlConfig(controller="osc")
    sim = make_simulation(
        SimConfig(task="pick-place-can", action_mode=control.action_mode, robot="Panda")
    )
    near_at, closed_at, steps = [], [], []

    def watch(step):
        steps.append(step)
        hand = sim.robot_state().end_effector.position
        if np.linalg.norm(hand - sim.object_poses()["Can"].position) < 0.015:
            near_at.append(len(steps))
        if step.command.gripper_closed:
            closed_at.append(len(steps))

    try:
        operator = ScriptedOperator(sim, control.mapping, seed=1234)
        result = run_episode(Teleoperator(sim, control), operator, seed, on_step=watch)
    finally:
        sim.close()
    assert result.success
    assert closed_at[0] - near_at[0] <= 20  # steps of 50 ms
