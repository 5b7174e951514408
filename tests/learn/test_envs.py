"""The Gymnasium environments, as a learner sees them: Gymnasium's own checker passes, the
reward is sparse (1 on every solved step), training episodes stop at the paper's 100-step
horizon, and bad actions are refused with a clear error; plain robosuite rebuilt from the
dataset's env_args is the same environment to a policy (spaces, observation keys, success)."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from crowdteleop.errors import InvalidActionError
from crowdteleop.learn.data import dataset_env_args
from crowdteleop.learn.demo_states import StartState, load_demo_states
from crowdteleop.learn.envs import PAPER_HORIZON, EnvSettings, make_env, robosuite_scene


@pytest.fixture(scope="module")
def demos(lift_dataset):
    return load_demo_states(lift_dataset)


@pytest.fixture
def env(demos):
    env = make_env(EnvSettings(sim_config=demos.sim_config), demos)
    yield env
    env.close()


def test_gymnasiums_checker_passes(env):
    check_env(env, skip_render_check=True)


def test_spaces_are_the_simulations_own(env):
    assert env.action_space.shape == (env.sim.action_spec.size,)
    np.testing.assert_array_equal(env.action_space.low, env.sim.action_spec.low)
    obs, _ = env.reset(seed=0)
    # robot0_eef_pos 3 + eef_quat 4 + gripper_qpos 2 + Lift's object-state 10
    assert obs.shape == env.observation_space.shape == (19,)
    assert obs.dtype == np.float32


def test_the_reward_is_one_on_solved_steps_and_zero_elsewhere(env, demos):
    demo = demos.demos[0]
    _, info = env.reset(options={"start": StartState(0, len(demo) - 1)})
    assert info["start"] == "demo" and info["success"], "a successful demo ends solved"
    _, reward, terminated, _, info = env.step(np.zeros(7, dtype=np.float32))
    assert reward == 1.0 and info["success"]
    assert not terminated, "the paper's return counts every solved step: no early stop"
    env.reset(options={"start": StartState(0, 0)})
    _, reward, *_ = env.step(np.zeros(7, dtype=np.float32))
    assert reward == 0.0


def test_training_episodes_are_truncated_at_the_papers_horizon(env):
    env.reset(seed=1)
    flags = [env.step(env.action_space.sample())[2:4] for _ in range(PAPER_HORIZON)]
    assert flags[-1] == (False, True)
    assert not any(truncated for _, truncated in flags[:-1])


def test_terminate_on_success_ends_the_episode_when_solved(demos):
    env = make_env(EnvSettings(sim_config=demos.sim_config, terminate_on_success=True), demos)
    try:
        env.reset(options={"start": StartState(0, len(demos.demos[0]) - 1)})
        assert env.step(np.zeros(7, dtype=np.float32))[2] is True
    finally:
        env.close()


def test_a_nan_action_is_refused_with_a_clear_error(env):
    env.reset(seed=0)
    with pytest.raises(InvalidActionError, match="NaN"):
        env.step(np.full(7, np.nan, dtype=np.float32))
    env.step(np.zeros(7, dtype=np.float32))  # and the environment goes on


def test_camera_observations_are_an_image_beside_the_low_dim_vector(demos):
    settings = EnvSettings(sim_config=demos.sim_config, camera="frontview", image_size=64)
    env = make_env(settings)
    try:
        obs, _ = env.reset(seed=0)
        assert obs["image"].shape == (64, 64, 3) and obs["image"].dtype == np.uint8
        assert obs["image"].std() > 5, "a rendered scene, not a blank frame"
        assert obs["low_dim"].shape == (19,)
        assert env.observation_space.contains(obs)
    finally:
        env.close()


def test_an_unknown_observation_key_names_the_ones_there_are(demos):
    with pytest.raises(ValueError, match="robot0_eef_pos"):
        make_env(EnvSettings(sim_config=demos.sim_config, obs_keys=("no_such_key",)))


@pytest.fixture(scope="module")
def scene(lift_dataset):
    return robosuite_scene(dataset_env_args(lift_dataset))


@pytest.fixture
def plain(demos, scene):
    env = make_env(EnvSettings(sim_config=demos.sim_config), sim="robosuite", scene=scene)
    yield env
    env.close()


def test_gymnasiums_checker_passes_on_plain_robosuite(plain):
    check_env(plain, skip_render_check=True)


def test_both_simulations_are_the_same_environment_to_a_policy(env, plain):
    assert plain.observation_space == env.observation_space
    assert plain.action_space == env.action_space
    assert set(plain.named_observations()) == set(env.named_observations())
    for each in (env, plain):
        obs, info = each.reset(seed=3)
        assert obs.dtype == np.float32 and info["success"] is False
        _, reward, _, _, info = each.step(np.zeros(7, dtype=np.float32))
        assert reward == 0.0 and info["success"] is False
        with pytest.raises(InvalidActionError, match="NaN"):
            each.step(np.full(7, np.nan, dtype=np.float32))


def test_plain_robosuite_starts_no_episode_from_demonstrations(demos, scene):
    with pytest.raises(ValueError, match="demonstration"):
        make_env(EnvSettings(sim_config=demos.sim_config), demos, sim="robosuite", scene=scene)


def test_plain_robosuite_gives_the_same_camera_observations(demos, scene):
    settings = EnvSettings(sim_config=demos.sim_config, camera="frontview", image_size=64)
    envs = [make_env(settings), make_env(settings, sim="robosuite", scene=scene)]
    try:
        ours, plain = (env.reset(seed=0)[0] for env in envs)
        assert envs[1].observation_space == envs[0].observation_space
        assert envs[1].observation_space.contains(plain)
        # the same scene from the same camera, upright in both (MuJoCo's rows run bottom-up)
        difference = np.abs(ours["image"].astype(int) - plain["image"].astype(int)).mean()
        assert difference < 10, difference
    finally:
        for env in envs:
            env.close()


def test_plain_robosuites_first_observation_places_the_can_relative_to_the_hand():
    """robosuite's own reset gives zeros for the object-to-hand sensors of pick-place (its
    cache is emptied and they read the object's pose before it is refilled); a policy's first
    input in plain robosuite is the scene's, as in ours and in the datasets."""
    from crowdteleop.provenance.env_args import EnvArgs
    from crowdteleop.recording.metadata import robosuite_version
    from crowdteleop.sim import SimConfig

    config = SimConfig(task="pick-place-can", robot="Panda", action_mode="osc-pose")
    scene = robosuite_scene(EnvArgs.of(config, robosuite_version()).model_dump(mode="json"))
    settings = EnvSettings(sim_config=config.model_dump(mode="json"))
    env = make_env(settings, sim="robosuite", scene=scene)
    try:
        for seed in (0, 1):
            env.reset(seed=seed)
            named = env.named_observations()
            can, hand = named["object"][7:10], named["robot0_eef_pos"]  # Can_pos, the hand
            relative = named["object"][0:3]  # Can_to_robot0_eef_pos, in the hand's frame
            distance = np.linalg.norm(can - hand)
            assert distance > 0.05
            assert np.linalg.norm(relative) == pytest.approx(distance, abs=1e-3)
    finally:
        env.close()
