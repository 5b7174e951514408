"""`actions_abs`: the same goals robosuite's own OSC computes from the delta actions, and back."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest

from crowdteleop.dataset.absolute import AbsoluteTargets
from crowdteleop.dataset.build import build_dataset
from crowdteleop.dataset.robosuite_replay import REPLAY_KWARGS
from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig
from crowdteleop.sim import SimConfig, make_simulation


@pytest.fixture(scope="module")
def osc_dataset(tmp_path_factory):
    folder = tmp_path_factory.mktemp("abs")
    with scripted_rig("lift", controller="osc") as rig:
        record_scripted_episode(rig, folder / "episodes", "ep-1", 4)
    build_dataset([folder / "episodes"], folder / "lift.hdf5")
    return folder / "lift.hdf5"


def test_absolute_targets_are_robosuites_own_delta_to_abs_action(osc_dataset):
    import robosuite

    with h5py.File(osc_dataset, "r") as file:
        env_args = json.loads(file["data"].attrs["env_args"])
        demo = file["data/demo_1"]
        states, actions, absolute = demo["states"][()], demo["actions"][()], demo["actions_abs"][()]
        model_file = str(demo.attrs["model_file"])
    env = robosuite.make(env_args["env_name"], **(env_args["env_kwargs"] | REPLAY_KWARGS))
    try:
        env.reset_from_xml_string(model_file)
        robot = env.robots[0]
        arm = robot.composite_controller.part_controllers["right"]
        for k in range(0, len(states), 7):
            env.sim.set_state_from_flattened(states[k])
            env.sim.forward()
            robot.composite_controller.update_state()
            arm.update(force=True)
            theirs = arm.delta_to_abs_action(arm.scale_action(actions[k][:6]), "achieved")
            # robosuite converts through float32 quaternions: 1e-6
            np.testing.assert_allclose(absolute[k][:6], theirs, atol=1e-6)
    finally:
        env.close()


def test_an_absolute_target_turns_back_into_the_delta_that_set_it(osc_dataset):
    with h5py.File(osc_dataset, "r") as file:
        env_args = json.loads(file["data"].attrs["env_args"])
        demo = file["data/demo_1"]
        states, actions, absolute = demo["states"][()], demo["actions"][()], demo["actions_abs"][()]
    sim = make_simulation(SimConfig(task="lift", action_mode="osc-pose"))
    try:
        arm = env_args["env_kwargs"]["controller_configs"]["body_parts"]["right"]
        targets = AbsoluteTargets(sim.kinematics(), arm)
        back = np.array([targets.to_delta(s, t) for s, t in zip(states, absolute, strict=True)])
    finally:
        sim.close()
    np.testing.assert_allclose(back, actions, atol=1e-9)
