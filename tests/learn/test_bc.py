"""BC-RNN end to end, tiny: a few scripted lift demos, a few hundred gradient steps, one short
rollout in each simulation. Checks behaviour, not success: the loss falls, a checkpoint
reloads to the same actions, both evaluators run the policy and report what they saw."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from crowdteleop.cli import app
from crowdteleop.learn.bc import Policy, load_checkpoint, train_bc
from crowdteleop.learn.config import STOCK_OBS_KEYS, BCConfig
from crowdteleop.learn.data import LearnDataError, SequenceSampler, load_learn_data
from crowdteleop.learn.envs import robosuite_scene
from crowdteleop.learn.evaluation import evaluate_checkpoint

runner = CliRunner()
SMALL = {"hidden_dim": 64, "batch_size": 32, "steps_per_epoch": 40, "learning_rate": 1e-3}


@pytest.fixture(scope="module")
def trained(lift_dataset, tmp_path_factory):
    torch.set_num_threads(1)
    output = tmp_path_factory.mktemp("bc")
    report = train_bc(lift_dataset, output, BCConfig(epochs=3, head="gmm", **SMALL))
    return report


def test_the_dataset_reads_as_stock_low_dim_keys_and_the_split(lift_dataset):
    data = load_learn_data(lift_dataset, STOCK_OBS_KEYS)
    assert data.obs_dims == (3, 4, 2, 10)  # eef pos, eef quat, finger joints, cube state
    assert len(data.train) == 2 and len(data.valid) == 1
    assert data.action_dim == 7  # OSC_POSE delta + gripper
    assert data.env_args["env_name"] == "Lift" and data.sim_config["action_mode"] == "osc-pose"
    with pytest.raises(LearnDataError, match="lacks observation keys"):
        load_learn_data(lift_dataset, ("robot0_eef_pos", "no_such_key"))


def test_windows_past_a_demos_end_repeat_its_last_step(lift_dataset):
    demo = load_learn_data(lift_dataset, STOCK_OBS_KEYS).train[0]
    sampler = SequenceSampler([demo], seq_length=10)
    obs, actions = sampler.windows(np.array([len(demo.actions) - 3]))
    assert obs.shape == (1, 10, 19) and actions.shape == (1, 10, 7)
    np.testing.assert_array_equal(obs[0, 2:], np.repeat(demo.obs[-1:], 8, axis=0))
    np.testing.assert_array_equal(actions[0, :3], demo.actions[-3:])


def test_training_lowers_the_loss_and_logs_every_epoch(trained):
    assert [row.epoch for row in trained.epochs] == [1, 2, 3]
    assert trained.epochs[-1].train_loss < trained.epochs[0].train_loss
    lines = trained.log.read_text().splitlines()
    assert lines[0] == "epoch,train_loss,valid_loss,valid_action_mse,seconds"
    assert len(lines) == 4
    assert (trained.checkpoint.parent / "model_best_valid.pt").exists()


def test_the_checkpoint_reloads_to_the_same_actions(trained, lift_dataset):
    data = load_learn_data(lift_dataset, STOCK_OBS_KEYS)
    demo = data.train[0]
    sizes = np.cumsum((0, *data.obs_dims))
    frames = [
        {key: row[sizes[i] : sizes[i + 1]] for i, key in enumerate(STOCK_OBS_KEYS)}
        for row in demo.obs[:15]
    ]

    def actions(policy):
        policy.reset(seed=3)
        return np.array([policy.act(frame) for frame in frames])

    first, again = load_checkpoint(trained.checkpoint), load_checkpoint(trained.checkpoint)
    np.testing.assert_array_equal(actions(Policy(first)), actions(Policy(again)))
    # the policy differs from an untrained one: the weights were saved, not the initial ones
    assert first.epoch == 3 and first.dataset["env_args"]["env_name"] == "Lift"
    assert np.all(np.abs(actions(Policy(first))) <= first.norm.action_scale + 1e-9)


@pytest.fixture(scope="module")
def deterministic(lift_dataset, tmp_path_factory):
    """A deterministic-head twin: its actions depend on the LSTM state alone (no sampling)."""
    config = BCConfig(epochs=1, head="deterministic", **SMALL)
    return train_bc(lift_dataset, tmp_path_factory.mktemp("bc-det"), config)


def test_the_lstm_state_restarts_every_horizon_as_robomimic_does(deterministic, lift_dataset):
    checkpoint = load_checkpoint(deterministic.checkpoint)
    demo = load_learn_data(lift_dataset, STOCK_OBS_KEYS).train[0]
    sizes = np.cumsum((0, *checkpoint.obs_dims))
    frame = {k: demo.obs[0][sizes[i] : sizes[i + 1]] for i, k in enumerate(checkpoint.obs_keys)}
    restarting, carried = Policy(checkpoint, rnn_horizon=2), Policy(checkpoint, rnn_horizon=0)
    restarting.reset()
    carried.reset()
    a = [restarting.act(frame) for _ in range(3)]
    b = [carried.act(frame) for _ in range(3)]
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[2], a[0])  # step 3 starts from a zero state again
    assert not np.allclose(b[2], b[0])  # the carried state changes the answer
    assert deterministic.epochs[0].valid_action_mse is not None


@pytest.mark.parametrize("sim", ["ours", "robosuite"])
def test_a_rollout_runs_in_each_simulation(trained, sim):
    checkpoint = load_checkpoint(trained.checkpoint)
    report = evaluate_checkpoint(checkpoint, sim, seeds=[0], horizon=5, trace=True)
    (episode,) = report.episodes
    assert episode.steps == 5 and not episode.success  # 5 steps cannot lift the cube
    assert np.array(episode.trace["action"]).shape == (5, 7)
    assert np.array(episode.trace["object"]).shape == (5, 10)
    assert report.summary()["success_rate"] == 0.0


def test_episode_k_starts_from_the_same_scene_every_time_in_each_simulation(trained):
    """Seeded episodes: a rerun compares like with like. (The two simulations' scenes differ:
    plain robosuite's hard reset redraws the cube's size from env.rng before placing it.)"""
    from crowdteleop.learn.evaluation import open_env

    checkpoint = load_checkpoint(trained.checkpoint)
    for sim in ("ours", "robosuite"):
        with open_env(checkpoint, sim) as env:
            starts = []
            for seed in (0, 1, 0):
                env.reset(seed=seed)
                starts.append(env.named_observations()["object"][:3])
        np.testing.assert_array_equal(starts[0], starts[2])
        assert not np.allclose(starts[0], starts[1])


def test_plain_robosuite_gets_headless_defaults_only_where_env_args_is_silent():
    kwargs = robosuite_scene(
        {"env_name": "Lift", "env_kwargs": {"robots": ["Sawyer"], "ignore_done": False}}
    ).env_kwargs
    assert kwargs["ignore_done"] is False and kwargs["has_renderer"] is False
    assert kwargs["robots"] == ["Sawyer"]


def test_the_cli_trains_and_evaluates(lift_dataset, tmp_path):
    output = tmp_path / "run"
    result = runner.invoke(
        app,
        [
            "learn",
            "bc",
            str(lift_dataset),
            "--output",
            str(output),
            "--epochs",
            "1",
            "--steps-per-epoch",
            "3",
            "--hidden-dim",
            "16",
            "--batch-size",
            "8",
        ],
    )
    assert result.exit_code == 0, result.output
    assert (output / "model.pt").exists() and (output / "log.csv").exists()
    result = runner.invoke(
        app,
        [
            "learn",
            "eval",
            str(output / "model.pt"),
            "--episodes",
            "1",
            "--sim",
            "ours",
            "--horizon",
            "3",
        ],
    )
    assert result.exit_code == 0, result.output
    written = json.loads((output / "eval.json").read_text())
    assert written["results"]["ours"]["episodes"] == 1
    assert "ours" in result.output
    import av

    with av.open(str(output / "eval.mp4")) as video:  # the rollout, filmed in ours
        assert sum(1 for _ in video.decode(video=0)) == 3


def test_a_dataset_without_observations_is_refused_with_what_to_do(lift_dataset, tmp_path):
    import h5py

    bare = tmp_path / "bare.hdf5"
    with h5py.File(lift_dataset, "r") as source, h5py.File(bare, "w") as target:
        for name in ("data", "mask"):
            source.copy(source[name], target, name=name)
        for demo in target["data"]:
            del target["data"][demo]["obs"]
    result = runner.invoke(app, ["learn", "bc", str(bare), "--output", str(tmp_path / "x")])
    assert result.exit_code == 2
    assert "--obs low-dim" in result.output


@pytest.fixture(scope="module")
def absolute(lift_dataset, tmp_path_factory):
    config = BCConfig(epochs=1, head="deterministic", actions="actions_abs", **SMALL)
    return load_checkpoint(
        train_bc(lift_dataset, tmp_path_factory.mktemp("bc-abs"), config).checkpoint
    )


def test_an_absolute_policy_learns_the_targets_in_their_continuous_form(absolute, lift_dataset):
    data = load_learn_data(lift_dataset, STOCK_OBS_KEYS, action_key="actions_abs")
    assert data.action_dim == 10  # position, two rotation columns, gripper
    assert data.abs_controller_configs["body_parts"]["right"]["input_type"] == "absolute"
    assert absolute.config.actions == "actions_abs"


@pytest.mark.parametrize("sim", ["ours", "robosuite"])
def test_an_absolute_policy_rolls_out_in_each_simulation(absolute, sim):
    report = evaluate_checkpoint(absolute, sim, seeds=[0], horizon=8, trace=True)
    (episode,) = report.episodes
    assert np.array(episode.trace["action"]).shape == (8, 7)  # the recorded actions_abs layout


def test_plain_robosuite_reads_absolute_targets_with_its_absolute_osc(absolute):
    from crowdteleop.learn.evaluation import open_env

    with open_env(absolute, "robosuite") as env:
        arm = env.backend.env.robots[0].part_controllers["right"]
        assert arm.input_type == "absolute" and arm.input_ref_frame == "base"


def test_the_open_loop_targets_of_a_demo_retrace_it_in_our_simulation(absolute, lift_dataset):
    """The recorded actions_abs, turned into deltas step by step, put the hand where the
    demo's own hand went: what makes an absolute policy's targets mean the same here."""
    import h5py

    from crowdteleop.learn.evaluation import open_env

    with h5py.File(lift_dataset) as file:
        group = file["data/demo_1"]
        targets, hands = group["actions_abs"][:40], group["obs/robot0_eef_pos"][1:41]
        seed = json.loads(group.attrs["metadata"])["reset_seed"]
        start = group["states"][0]
    with open_env(absolute, "ours") as env:
        env.reset(seed=seed)
        env.sim.set_state(start)
        reached = []
        for target in targets:
            env.step(target)
            reached.append(env.named_observations()["robot0_eef_pos"])
        reached = np.array(reached)
    assert np.max(np.linalg.norm(reached - hands, axis=1)) < 0.01


def test_an_absolute_policy_of_ik_velocity_demos_is_refused_in_our_simulation(absolute):
    from dataclasses import replace

    from crowdteleop.learn.evaluation import open_env
    from crowdteleop.provenance.controllers import CompositeController, JointPosition

    dataset = json.loads(json.dumps(absolute.dataset))
    servo = CompositeController.of(JointPosition.velocity_servo(1.0, 0.05))  # ik-velocity's
    dataset["env_args"]["env_kwargs"]["controller_configs"] = servo.to_robosuite()
    with (
        pytest.raises(LearnDataError, match="osc demos only"),
        open_env(replace(absolute, dataset=dataset), "ours"),
    ):
        pass


def test_both_simulations_bring_the_hand_to_the_same_absolute_target(absolute, lift_dataset):
    """A target's rotation (axis-angle components past 1 rad for a hand pointing down) reaches
    robosuite's absolute OSC unclipped: held for 15 steps, the hand settles on the same pose in
    both simulations."""
    import h5py
    from scipy.spatial.transform import Rotation

    from crowdteleop.learn.evaluation import open_env

    with h5py.File(lift_dataset) as file:
        target = file["data/demo_1/actions_abs"][0]  # near the start: Sawyer reaches it in both
    assert np.max(np.abs(target[3:6])) > 1.0
    reached = {}
    for sim in ("ours", "robosuite"):
        with open_env(absolute, sim) as env:
            env.reset(seed=0)
            for _ in range(15):
                env.step(target)
            obs = env.named_observations()
            reached[sim] = obs["robot0_eef_pos"], Rotation.from_quat(obs["robot0_eef_quat"])
    (pos_a, rot_a), (pos_b, rot_b) = reached["ours"], reached["robosuite"]
    assert np.linalg.norm(pos_a - pos_b) < 0.01
    assert np.degrees((rot_a * rot_b.inv()).magnitude()) < 3.0
