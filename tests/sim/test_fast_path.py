"""The fast path's shortcuts are invisible to users: a scene at rest only advances its clock
(an idle worker costs ~nothing) and wakes on the next real command; objects a task does not use
stay parked out of the way."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import ControlConfig
from crowdteleop.control.teleoperator import Teleoperator
from crowdteleop.errors import ConfigError
from crowdteleop.sim import SimConfig, make_simulation


def test_a_scene_at_rest_only_advances_time_and_wakes_on_a_command():
    sim = make_simulation(SimConfig(task="lift"))
    try:
        teleop = Teleoperator(sim, ControlConfig())
        teleop.reset(0)
        idle = DeviceCommand()
        for _ in range(150):  # the arm and cube settle
            teleop.step(idle)
        settled = sim.get_state()
        for _ in range(10):
            teleop.step(idle)
        now = sim.get_state()
        assert np.isclose(now[0], settled[0] + 10 * sim.control_dt)
        assert np.array_equal(now[1:], settled[1:])

        frozen = sim.get_state()
        teleop.step(idle)
        after_idle = sim.get_state()
        sim.set_state(frozen)
        teleop.step(idle)
        assert np.array_equal(sim.get_state(), after_idle)  # restore stays exact at rest

        for _ in range(10):
            teleop.step(DeviceCommand(gripper_closed=True))
        assert sim.robot_state().gripper_closed_fraction > 0.5
    finally:
        sim.close()


def test_objects_a_task_does_not_use_stay_parked():
    sim = make_simulation(SimConfig(task="pick-place-can"))
    try:
        sim.reset(seed=0)
        before = sim.get_state()
        action = np.zeros(sim.action_spec.size)
        action[-1] = -1.0
        for _ in range(40):
            result = sim.step(action)
        assert {c.object for c in result.contacts} <= {"Can"}
        assert set(sim.object_poses()) >= {"Can", "Can/target"}
        assert not {"Milk", "Bread", "Cereal"} & set(sim.object_poses())
        model = mujoco.MjModel.from_xml_string(sim.mjcf_xml())
        for name in ("Milk", "Bread", "Cereal"):
            address = 1 + model.jnt_qposadr[model.joint(f"{name}_joint0").id]
            parked_before = before[address : address + 3]
            assert np.array_equal(sim.get_state()[address : address + 3], parked_before)
    finally:
        sim.close()


def test_robosuite_step_leaves_the_fast_path_and_plain_mujoco_refuses_it():
    """SimConfig.robosuite_step: robosuite's own step whatever the task declares; a task on
    plain MuJoCo has no robosuite step, and says so."""
    sim = make_simulation(SimConfig(task="lift", robosuite_step=True))
    try:
        assert not sim.fast_path and sim.fast_path_obstacles == []
    finally:
        sim.close()
    with pytest.raises(ConfigError, match="no robosuite to step"):
        make_simulation(SimConfig(task="mujoco-lift", robosuite_step=True))
