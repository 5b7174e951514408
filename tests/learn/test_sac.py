"""SAC with demonstrations end to end, tiny: `crowdteleop learn rl --algo sac` clones the
demos into its actor before any interaction, trains a few hundred steps with half of every
batch from the demos, checkpoints with its replay buffer, resumes, and `learn eval` and `learn
table` read the run as they read PPO's. Checks the machinery, not learning: the long runs are
in benchmarks/learning.md."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from crowdteleop.cli import app
from crowdteleop.learn.config import STOCK_OBS_KEYS, SACConfig
from crowdteleop.learn.demo_buffer import DemoReplayBuffer, load_demo_transitions
from crowdteleop.learn.demo_states import load_demo_states
from crowdteleop.learn.envs import EnvSettings
from crowdteleop.learn.sac import DemoSAC, pretrain_actor

runner = CliRunner()


def invoke(*args):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result.output


@pytest.fixture(scope="module")
def run(lift_dataset, tmp_path_factory):
    """Trained to 300 steps, then resumed to 600."""
    output = tmp_path_factory.mktemp("sac")
    common = ["learn", "rl", "--algo", "sac", "--dataset", lift_dataset, "--demos", 2]
    common += ["--output", output, "--horizon", 60]
    invoke(*common, "--budget", 300)
    seed_dir = output / "seed_0"
    first = json.loads((seed_dir / "state.json").read_text())
    invoke(*common, "--budget", 600, "--resume")
    return seed_dir, first


def test_a_run_checkpoints_with_its_experience_and_a_resumed_run_continues_it(run):
    seed_dir, first = run
    second = json.loads((seed_dir / "state.json").read_text())
    assert 300 <= first["steps"] < 600 <= second["steps"]
    assert second["seconds"] > first["seconds"], "wall time adds up across the two"
    assert (seed_dir / "replay_buffer.pkl").stat().st_size > 0
    curve = list(csv.DictReader((seed_dir / "curve.csv").open()))
    assert int(curve[0]["steps"]) <= 1, "a point before any interaction"
    info = json.loads((seed_dir / "run.json").read_text())
    assert (info["algo"], info["task"], info["demos"]) == ("sac", "lift", 2)
    assert info["env"]["terminate_on_success"] is True and info["env"]["horizon"] == 60
    assert info["env_args"]["env_name"] == "Lift"


def test_the_checkpoint_keeps_the_runs_experience_not_the_demos(run):
    model = DemoSAC.load(str(run[0] / "model.zip"), device="cpu")
    model.load_replay_buffer(str(run[0] / "replay_buffer.pkl"))
    buffer = model.replay_buffer
    assert isinstance(buffer, DemoReplayBuffer) and buffer.demos is None, "demos are not saved"
    assert buffer.size() >= 600, "the run's own experience is"


def test_eval_and_table_read_a_sac_run(run, tmp_path):
    seed_dir, _ = run
    output = invoke("learn", "eval", seed_dir, "--episodes", 2, "--horizon", 30, "--video", 0)
    assert "ours" in output and "robosuite" in output
    results = json.loads((seed_dir / "eval.json").read_text())["results"]
    assert results["ours"]["episodes"] == 2 and results["robosuite"]["horizon"] == 30
    markdown = tmp_path / "table.md"
    plot = tmp_path / "curves.png"
    invoke("learn", "table", seed_dir.parent, "--markdown", markdown, "--plot", plot)
    text = markdown.read_text()
    assert "| lift (ours) | SAC, demos in its buffer |" in text
    training = next(
        line for line in text.splitlines() if "| SAC, demos in its buffer | lift | 2 | 1 |" in line
    )
    assert training.split("|")[-2].strip() != "-", "the training episodes' return is logged"
    assert plot.stat().st_size > 10_000


def test_cloning_brings_the_actor_to_the_demos_actions(lift_dataset):
    demos = load_demo_transitions(lift_dataset, 3, STOCK_OBS_KEYS)
    settings = EnvSettings(sim_config=load_demo_states(lift_dataset, 1).sim_config)
    config = SACConfig(demos=3, bc_steps=1500)
    from crowdteleop.learn.envs import make_env

    env = make_env(settings)
    try:
        model = DemoSAC("MlpPolicy", env, seed=0, device="cpu")
        obs = torch.as_tensor(demos.obs)

        def error() -> float:
            with torch.no_grad():
                return float(((model.actor(obs, deterministic=True) - demos.actions) ** 2).mean())

        before = error()
        pretrain_actor(model, demos, config)
        after = error()
    finally:
        env.close()
    assert after < 0.05 < before, (before, after)
    assert np.isfinite(after)


def test_pure_rl_needs_no_dataset_and_a_bad_algorithm_is_refused(tmp_path):
    invoke(
        "learn",
        "rl",
        "--algo",
        "sac",
        "--task",
        "lift",
        "--budget",
        50,
        "--horizon",
        25,
        "--output",
        tmp_path,
    )
    assert json.loads((tmp_path / "seed_0" / "run.json").read_text())["demos"] == 0
    result = runner.invoke(
        app, ["learn", "rl", "--algo", "dqn", "--task", "lift", "--output", str(tmp_path)]
    )
    assert result.exit_code != 0 and "dqn" in result.output


def test_the_critic_normalizes_each_hidden_layer_as_rlpds_does(run):
    model = DemoSAC.load(str(run[0] / "model.zip"), device="cpu")
    for network in model.critic.q_networks:
        kinds = [type(layer).__name__ for layer in network]
        assert kinds == ["Linear", "LayerNorm", "ReLU"] * 2 + ["Linear"], kinds
    assert len(model.critic.q_networks) == 2, "twin critics"


def _episode_start_hands(run_dir) -> np.ndarray:
    """The hand's position at the start of each training episode, from the saved buffer."""
    model = DemoSAC.load(str(run_dir / "model.zip"), device="cpu")
    model.load_replay_buffer(str(run_dir / "replay_buffer.pkl"))
    buffer = model.replay_buffer
    obs, ended = buffer.observations[: buffer.size(), 0], buffer.dones[: buffer.size(), 0]
    ended = np.maximum(ended, buffer.timeouts[: buffer.size(), 0])
    starts = np.concatenate([[0], np.flatnonzero(ended[:-1]) + 1])
    return obs[starts, :3]


def test_training_episodes_can_start_in_demo_states_as_the_papers_do(lift_dataset, tmp_path):
    for name, reset_p in (("normal", 0), ("demo", 1)):
        invoke(
            "learn",
            "rl",
            "--algo",
            "sac",
            "--dataset",
            lift_dataset,
            "--demos",
            2,
            "--demo-reset-p",
            reset_p,
            "--horizon",
            20,
            "--budget",
            200,
            "--output",
            tmp_path / name,
        )
    info = json.loads((tmp_path / "demo" / "seed_0" / "run.json").read_text())
    assert info["env"]["demo_reset_p"] == 1.0
    normal = _episode_start_hands(tmp_path / "normal" / "seed_0")
    demo = _episode_start_hands(tmp_path / "demo" / "seed_0")
    assert len(normal) >= 5 and len(demo) >= 5
    # normal resets start at the arm's home pose (a little joint noise); demo states anywhere
    # along the demos' reach, grasp and lift
    assert normal.std(axis=0).max() < 0.02 < demo.std(axis=0).max(), (normal, demo)


def _ibrl(lift_dataset, output, steps: int) -> DemoSAC:
    """IBRL trained to ``steps`` (resumed if ``output`` has a run), the actor free at once."""
    from crowdteleop.learn.config import IBRL_SETTINGS
    from crowdteleop.learn.sac import Demonstrations, train_sac

    settings = EnvSettings(
        sim_config=load_demo_states(lift_dataset, 1).sim_config,
        horizon=40,
        demo_reset_p=0.0,
        terminate_on_success=True,
    )
    config = SACConfig(
        **IBRL_SETTINGS, demos=2, total_steps=steps, warmup_steps=0, bc_steps=300, eval_every=10**6
    )
    demos = Demonstrations(load_demo_transitions(lift_dataset, 2, STOCK_OBS_KEYS))
    path = train_sac(config, settings, demos, output, resume=True, dataset=lift_dataset)
    return DemoSAC.load(str(path), device="cpu")


def test_ibrl_keeps_the_cloned_actor_frozen_while_the_learner_moves(lift_dataset, tmp_path):
    first = _ibrl(lift_dataset, tmp_path, 150)
    second = _ibrl(lift_dataset, tmp_path, 300)
    info = json.loads((tmp_path / "run.json").read_text())
    assert info["algo"] == "ibrl" and info["config"]["imitation_bootstrap"] is True
    frozen = [
        torch.equal(a, b)
        for a, b in zip(
            first.policy.imitation.parameters(), second.policy.imitation.parameters(), strict=True
        )
    ]
    moved = [
        torch.equal(a, b)
        for a, b in zip(first.actor.parameters(), second.actor.parameters(), strict=True)
    ]
    assert all(frozen) and not all(moved)
    assert not any(p.requires_grad for p in second.policy.imitation.parameters())
    shares = [
        float(r["train/imitation_share"])
        for r in csv.DictReader((tmp_path / "progress.csv").open())
        if r.get("train/imitation_share")
    ]
    assert shares and all(0 <= s <= 1 for s in shares), (
        "how often the TD target took the clone's action"
    )


def test_ibrl_acts_with_whichever_proposal_the_critic_values_higher(lift_dataset, tmp_path):
    from crowdteleop.learn.sac import lowest_q

    model = _ibrl(lift_dataset, tmp_path, 300)
    obs = torch.as_tensor(load_demo_transitions(lift_dataset, 2, STOCK_OBS_KEYS).obs)
    with torch.no_grad():
        clone = model.policy.imitation(obs, deterministic=True)
        learner = model.actor(obs, deterministic=True)
        prefer_clone = lowest_q(model.critic, obs, clone) > lowest_q(model.critic, obs, learner)
    expected = torch.where(prefer_clone, clone, learner).numpy()
    assert not np.allclose(clone.numpy(), learner.numpy()), "the learner has moved"
    acted, _ = model.predict(obs.numpy(), deterministic=True)
    np.testing.assert_allclose(acted, expected, atol=1e-6)
    # the same choice with the two networks' places swapped: the policy weighs both proposals,
    # so one of the two places' actions was overruled somewhere
    policy = model.policy
    policy.actor, policy.imitation = policy.imitation, policy.actor
    swapped, _ = model.predict(obs.numpy(), deterministic=True)
    np.testing.assert_allclose(swapped, expected, atol=1e-6)


def test_learn_rl_trains_ibrl_and_learn_table_names_it(lift_dataset, tmp_path):
    output = tmp_path / "runs"
    invoke(
        "learn",
        "rl",
        "--algo",
        "ibrl",
        "--dataset",
        lift_dataset,
        "--demos",
        2,
        "--budget",
        100,
        "--horizon",
        40,
        "--output",
        output,
    )
    info = json.loads((output / "seed_0" / "run.json").read_text())
    assert info["algo"] == "ibrl" and info["config"]["imitation_bootstrap"] is True
    invoke(
        "learn",
        "eval",
        output / "seed_0",
        "--episodes",
        1,
        "--horizon",
        20,
        "--video",
        0,
        "--sim",
        "ours",
    )
    markdown = tmp_path / "table.md"
    invoke("learn", "table", output, "--markdown", markdown)
    assert "SAC + IBRL (frozen clone proposes)" in markdown.read_text()
