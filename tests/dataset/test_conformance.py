"""Datasets the field's own tools accept unmodified: bot sessions through a real teleop server
(WebRTC, recorder, storage) -> `crowdteleop dataset build` -> robosuite's playback, plain
robosuite stepping the recorded actions, robomimic's `SequenceDataset` with its stock keys."""

from __future__ import annotations

import asyncio
import json

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from crowdteleop.cli import app
from crowdteleop.client.bot import Bot
from crowdteleop.client.connection import TeleopClient
from crowdteleop.dataset.build import build_dataset
from crowdteleop.dataset.check import STOCK_LOW_DIM, check_dataset
from crowdteleop.dataset.replay import ReplayChecker, load_demo
from crowdteleop.dataset.robosuite_replay import play_states_in_robosuite
from crowdteleop.dataset.summary import network_of
from tests.fixtures.teleop_process import ADMIN_TOKEN, TOKEN, run, teleop_server

runner = CliRunner()


def _bot_episodes(tmp_path, controller: str, robot: str, episodes: int) -> list:
    overrides = {"control": {"controller": controller}, "sim": {"robot": robot}}
    with teleop_server(tmp_path, **overrides) as server:

        async def scenario():
            client = TeleopClient(server.url, TOKEN, role="admin", admin_token=ADMIN_TOKEN)
            await client.connect()
            result = await Bot(client, seed=1).run(episodes=episodes, timeout_s=200)
            await asyncio.sleep(1.5)  # the last episode is finalized off the control loop
            await client.close()
            return result

        result = run(scenario(), timeout=300)
        assert result.episodes.count("success") == episodes
        return sorted((server.record_dir / "success").glob("*.hdf5"))


@pytest.mark.slow
@pytest.mark.parametrize(("controller", "robot"), [("osc", "Panda"), ("ik-velocity", "Sawyer")])
def test_bot_sessions_build_a_dataset_robosuite_and_robomimic_accept(tmp_path, controller, robot):
    files = _bot_episodes(tmp_path, controller, robot, episodes=2)
    dataset = tmp_path / f"{controller}.hdf5"
    build_dataset(files, dataset)

    with h5py.File(dataset, "r") as file:
        env_info = json.loads(file["data"].attrs["env_info"])
        env_args = json.loads(file["data"].attrs["env_args"])
        demo = file["data/demo_1"]
        actions, obs_keys = demo["actions"][()], set(demo["obs"])
        network = demo.attrs["network_condition"]
        telemetry = demo.attrs["telemetry"]
    assert {"env_name", "robots", "controller_configs"} <= set(env_info)
    assert "control_freq" not in env_info, "robosuite's playback passes control_freq itself"
    assert env_args["env_kwargs"]["control_freq"] == 20
    assert set(STOCK_LOW_DIM) <= obs_keys
    assert actions.shape[1] == (7 if controller == "osc" else 8)
    assert network == "baseline", f"loopback is not a slow link: {telemetry}"

    # robosuite's own playback: robosuite.make(**env_info), the model file, every state exact
    for name in ("demo_1", "demo_2"):
        playback = play_states_in_robosuite(str(dataset), name)
        assert playback.max_state_error == 0.0
        assert playback.success_at_end

    # the recorded actions mean in plain robosuite (built from env_args) what they meant here
    with ReplayChecker() as checker:
        drift = checker.robosuite_drift(load_demo(dataset, "demo_1"), env_args)
    assert drift.per_step_median_m < 0.001
    assert drift.per_step_max_m < 0.003

    checks = check_dataset(dataset, demos=2)
    verdicts = {r.name: r.verdict for r in checks}
    details = {r.name: r.detail for r in checks}
    result = runner.invoke(app, ["dataset", "check", str(dataset), "--demos", "1"])
    if robot == "Sawyer":
        # our Sawyer model excludes its base contact; robosuite's own (from env_args) keeps it
        assert verdicts.pop("scene from env_args") == "fail"
        assert (
            "robot0_right_arm_base_link/robot0_right_l0 (100% of states)"
            in details["scene from env_args"]
        )
        assert "scene from env_args" in result.output
        assert result.exit_code == 1
    else:
        assert result.exit_code == 0, result.output
    assert set(verdicts.values()) == {"pass"}, verdicts


def test_robomimic_sequence_dataset_reads_the_stock_low_dim_keys(tmp_path):
    import robomimic.utils.obs_utils as obs_utils
    from robomimic.utils.dataset import SequenceDataset

    from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

    with scripted_rig("lift", controller="osc") as rig:
        for seed in (1, 2):
            record_scripted_episode(rig, tmp_path / "episodes", f"ep-{seed}", seed)
    dataset = tmp_path / "lift.hdf5"
    build_dataset([tmp_path / "episodes"], dataset)
    obs_utils.initialize_obs_utils_with_obs_specs(
        {"obs": {"low_dim": list(STOCK_LOW_DIM), "rgb": []}}
    )
    loaded = SequenceDataset(
        hdf5_path=str(dataset),
        obs_keys=STOCK_LOW_DIM,
        dataset_keys=("actions", "rewards", "dones"),
        load_next_obs=True,
        frame_stack=1,
        seq_length=10,
        pad_frame_stack=True,
        pad_seq_length=True,
        get_pad_mask=False,
        goal_mode=None,
        hdf5_cache_mode="all",
        hdf5_use_swmr=True,
        hdf5_normalize_obs=False,
        filter_by_attribute=None,
    )
    sample = loaded[0]
    assert sample["obs"]["robot0_eef_pos"].shape == (10, 3)
    assert sample["obs"]["robot0_eef_quat"].shape == (10, 4)
    assert sample["obs"]["robot0_gripper_qpos"].shape == (10, 2)
    assert sample["obs"]["object"].shape == (10, 10)  # Lift: cube pos, quat, cube - hand
    assert sample["next_obs"]["robot0_eef_pos"].shape == (10, 3)
    with h5py.File(dataset, "r") as file:
        demo = file["data/demo_1"]
        np.testing.assert_array_equal(
            demo["obs/robot0_eef_pos"][1:], demo["next_obs/robot0_eef_pos"][:-1]
        )


def test_observations_are_plain_robosuites_own(lift_osc_states):
    """Our observables, computed on our data, equal plain robosuite's after the same state."""
    import robosuite

    from crowdteleop.sim import SimConfig, make_simulation
    from crowdteleop.sim.types import low_dim_keys

    sim = make_simulation(SimConfig(task="lift", action_mode="osc-pose"))
    env = robosuite.make(
        "Lift",
        robots="Sawyer",
        has_renderer=False,
        has_offscreen_renderer=False,
        use_camera_obs=False,
        ignore_done=True,
        hard_reset=False,
    )
    try:
        env.reset_from_xml_string(sim.mjcf_xml())
        for state in lift_osc_states(sim):
            sim.set_state(state)
            ours = sim.observations()
            env.sim.set_state_from_flattened(state)
            env.sim.forward()
            theirs = low_dim_keys(env._get_observations(force_update=True))
            assert set(ours) == set(theirs)
            for key in ("robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos", "object"):
                np.testing.assert_allclose(ours[key], theirs[key], atol=1e-9, err_msg=key)
    finally:
        env.close()
        sim.close()


@pytest.fixture
def lift_osc_states():
    def states(sim):
        sim.reset(3)
        action = np.zeros(sim.action_spec.size)
        out = []
        for i in range(30):
            action[0], action[2], action[-1] = 0.5, -0.3, 1.0 if i > 15 else -1.0
            sim.step(action)
            out.append(sim.get_state())
        return out

    return states


def test_the_network_label_comes_from_the_link_not_the_encoder():
    # measured on loopback: aiortc's receiver estimate follows the 300-500 kbps it receives
    loopback = {
        "rtt_ms": 7.5,
        "rtt_min_ms": 2.1,
        "bitrate_kbps": 311.8,
        "receiver_kbps": 331.7,
        "loss_fraction": 0.0,
    }
    assert network_of({"telemetry": loopback}) == "baseline", "a low estimate alone is no link"
    queued = loopback | {"rtt_ms": 420.0, "rtt_min_ms": 45.0}
    assert network_of({"telemetry": queued}) == "low-capacity", "a queue behind a low estimate"
    far = loopback | {"rtt_ms": 250.0, "rtt_min_ms": 241.0}
    assert network_of({"telemetry": far}) == "high-delay"
    both = loopback | {"rtt_ms": 700.0, "rtt_min_ms": 241.0}
    assert network_of({"telemetry": both}) == "both"
    lossy = loopback | {"loss_fraction": 0.05}
    assert network_of({"telemetry": lossy}) == "low-capacity+lossy"
    assert network_of({"network_condition": "low-capacity", "telemetry": {}}) == "low-capacity"
    assert network_of({}) == "unknown"
