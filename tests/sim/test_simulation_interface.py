"""Every task, on both backends, honours the `Simulation` contract."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.sim.interface import Simulation
from crowdteleop.tasks import task_names
from crowdteleop.vocab import TABLE_CONTACT
from tests.fixtures.motion import arm_motion

ALL_TASKS = task_names()


@pytest.fixture(params=ALL_TASKS, scope="module")
def sim(request: pytest.FixtureRequest):
    simulation = make_simulation(SimConfig(task=request.param))
    yield simulation
    simulation.close()


def test_is_a_simulation_with_the_papers_control_rate(sim):
    assert isinstance(sim, Simulation)
    assert sim.control_dt == pytest.approx(0.05)
    assert sim.action_spec.mode == "joint-velocity"
    assert sim.action_spec.size == len(sim.kinematics().arm_joints) + 1


def test_same_seed_same_start_and_other_seed_other_start(sim):
    sim.reset(seed=7)
    first = sim.get_state()
    sim.reset(seed=8)
    other = sim.get_state()
    sim.reset(seed=7)
    assert np.array_equal(sim.get_state(), first)
    assert not np.array_equal(first, other)


def test_renders_a_non_blank_frame_that_changes_when_the_arm_moves(sim):
    sim.reset(seed=1)
    camera = "frontview"
    before = sim.render(camera, 320, 240)
    assert before.shape == (240, 320, 3) and before.dtype == np.uint8
    assert before.std() > 20, "frame is blank"
    for index in range(15):
        sim.step(arm_motion(sim, index))
    after = sim.render(camera, 320, 240)
    changed = np.any(np.abs(before.astype(int) - after.astype(int)) > 30, axis=2)
    assert changed.mean() > 0.002, "the arm moved but the picture did not change"
    assert sim.render(camera, 480, 360).shape == (360, 480, 3)


def test_restoring_a_state_reproduces_the_next_step_and_render_bit_for_bit(sim):
    sim.reset(seed=2)
    for index in range(5):
        sim.step(arm_motion(sim, index))
    saved = sim.get_state()
    action = arm_motion(sim, 99)
    first = sim.step(action)
    first_state, first_frame = sim.get_state(), sim.render("frontview", 160, 120)
    for index in range(3):  # wander off
        sim.step(arm_motion(sim, 50 + index))
    sim.set_state(saved)
    second = sim.step(action)
    assert np.array_equal(sim.get_state(), first_state)
    assert np.array_equal(sim.render("frontview", 160, 120), first_frame)
    assert (second.reward, second.success) == (first.reward, first.success)


def test_reports_progress_poses_contacts_and_its_model(sim):
    sim.reset(seed=3)
    result = sim.step(arm_motion(sim, 0))
    assert result.progress is not None and result.progress.total >= 1
    assert result.progress.message
    assert isinstance(result.contacts, list)
    assert sim.success() is False
    poses = sim.object_poses()
    assert poses and all(np.all(np.isfinite(p.position)) for p in poses.values())
    robot = sim.robot_state()
    assert np.isclose(np.linalg.norm(robot.end_effector.quaternion), 1.0)
    assert 0.0 <= robot.gripper_closed_fraction <= 1.0
    model = mujoco.MjModel.from_xml_string(sim.mjcf_xml())
    assert 1 + model.nq + model.nv == sim.get_state().shape[0]


def test_its_contacts_can_name_the_table_and_the_arm_at_rest_stands_clear_of_it(sim):
    """The table (on pick-place, the bins) is among what contacts name, so touches of it are
    recorded and counted; a robot whose base touched it would count a touch every step."""
    assert TABLE_CONTACT in sim.contact_objects
    assert set(sim.object_poses()) & set(sim.contact_objects) - {TABLE_CONTACT}
    sim.reset(seed=4)
    for _ in range(5):
        result = sim.step(np.zeros(sim.action_spec.size))
        assert [c for c in result.contacts if c.object == TABLE_CONTACT] == []
