"""Demonstration-guided PPO end to end, tiny: a few hundred steps through `crowdteleop learn
rl` (subprocess environments, demo resets), a checkpoint, a resumed run that continues it,
`learn eval` in both simulations with an MP4, and `learn table` over the result. Checks the
machinery, not learning: the long runs are in benchmarks/learning.md."""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy
from typer.testing import CliRunner

from crowdteleop.cli import app
from crowdteleop.learn.cli import parse_budget
from crowdteleop.learn.config import PPOConfig
from crowdteleop.learn.demo_states import DemoStates, load_demo_states
from crowdteleop.learn.envs import EnvSettings
from crowdteleop.learn.ppo import normalized_env
from crowdteleop.learn.ppo_policy import process_sequence
from crowdteleop.learn.vec import make_vec_env

runner = CliRunner()


def invoke(*args):
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result.output


def test_whole_sequence_lstm_passes_match_sb3s_step_by_step_ones():
    torch.manual_seed(0)
    lstm = torch.nn.LSTM(5, 8)
    n_seq, length = 6, 12
    features = torch.randn(n_seq * length, 5)
    states = (torch.randn(1, n_seq, 8), torch.randn(1, n_seq, 8))
    starts = torch.zeros(n_seq, length)
    starts[::2, 0] = 1.0  # half the sequences begin an episode
    ours, (h, c) = process_sequence(features, states, starts.reshape(-1), lstm)
    theirs, (h2, c2) = RecurrentActorCriticPolicy._process_sequence(
        features, states, starts.reshape(-1), lstm
    )
    torch.testing.assert_close(ours, theirs)
    torch.testing.assert_close(h, h2)
    torch.testing.assert_close(c, c2)


def test_budgets_read_as_steps_or_wall_time():
    assert parse_budget("200k") == (200_000, None)
    assert parse_budget("1.5M") == (1_500_000, None)
    assert parse_budget("30m") == (None, 1800.0)
    assert parse_budget("2h") == (None, 7200.0)


def solved_episode(dataset, normalize_reward: bool, steps: int = 8):
    """An episode started in a demo's last (solved) state, its last action held: the rewards
    the learner saw, the task's own ones, and the return the training log counts."""
    demos = load_demo_states(dataset, 1)
    last = [
        replace(d, states=d.states[-1:], controller_states=d.controller_states[-1:])
        for d in demos.demos
    ]
    settings = EnvSettings(sim_config=demos.sim_config, horizon=steps, demo_reset_p=1.0)
    config = PPOConfig(normalize_reward=normalize_reward)
    venv = normalized_env(make_vec_env(settings, DemoStates(last), 1, "dummy", 0), config, None)
    try:
        venv.reset()
        action = demos.demos[0].actions[-1:].astype(np.float32)
        seen, own, logged = [], [], None
        for _ in range(steps):
            _, reward, _, infos = venv.step(action)
            seen.append(float(reward[0]))
            own.append(float(venv.get_original_reward()[0]))
            logged = infos[0].get("episode", {}).get("r", logged)
        return seen, own, logged
    finally:
        venv.close()


def test_the_learner_sees_scaled_rewards_while_the_log_counts_the_tasks_own(lift_dataset):
    seen, own, logged = solved_episode(lift_dataset, normalize_reward=True)
    assert own == [1.0] * len(own), "a held, lifted cube is solved at every step"
    assert logged == sum(own), "the training return is the task's own"
    assert all(0 < r <= 10 for r in seen) and seen != own, "the critic's rewards are scaled"
    seen, own, _ = solved_episode(lift_dataset, normalize_reward=False)
    assert seen == own


@pytest.fixture(scope="module")
def run(lift_dataset, tmp_path_factory):
    """Trained to 256 steps, then resumed to 512."""
    output = tmp_path_factory.mktemp("ppo")
    common = ["learn", "rl", "--dataset", lift_dataset, "--demos", 2, "--output", output]
    common += ["--n-envs", 2, "--vec", "subproc", "--n-steps", 64, "--eval-every", 128]
    invoke(*common, "--budget", 256)
    seed_dir = output / "seed_0"
    first = json.loads((seed_dir / "state.json").read_text())
    invoke(*common, "--budget", 512, "--resume")
    return seed_dir, first


def test_a_run_checkpoints_and_a_resumed_run_continues_it(run):
    seed_dir, first = run
    second = json.loads((seed_dir / "state.json").read_text())
    assert 256 <= first["steps"] < 512 <= second["steps"]
    assert second["seconds"] > first["seconds"], "wall time adds up across the two"
    curve = list(csv.DictReader((seed_dir / "curve.csv").open()))
    steps = [int(row["steps"]) for row in curve]
    assert steps == sorted(steps) and steps[-1] > first["steps"], "the curve goes on"
    info = json.loads((seed_dir / "run.json").read_text())
    assert (info["algo"], info["task"], info["demos"]) == ("ppo", "lift", 2)
    assert info["env_args"]["env_name"] == "Lift"
    assert info["config"]["lstm_hidden"] == 100 and info["config"]["net_arch"] == [300, 200]


def test_the_policy_is_the_papers_lstm_100_then_300_200(run):
    from sb3_contrib import RecurrentPPO

    model = RecurrentPPO.load(str(run[0] / "model.zip"), device="cpu")
    policy = model.policy
    assert policy.lstm_actor.hidden_size == 100 and policy.lstm_critic.hidden_size == 100
    widths = [m.out_features for m in policy.mlp_extractor.policy_net if hasattr(m, "out_features")]
    assert widths == [300, 200]
    assert policy.log_std.shape == (7,), "a learned, state-independent log-std"


def test_eval_reports_return_and_success_in_both_simulations_with_a_video(run):
    seed_dir, _ = run
    output = invoke("learn", "eval", seed_dir, "--episodes", 2, "--horizon", 40, "--video", 1)
    assert "ours" in output and "robosuite" in output
    results = json.loads((seed_dir / "eval.json").read_text())["results"]
    for sim in ("ours", "robosuite"):
        summary = results[sim]
        assert summary["episodes"] == 2 and summary["horizon"] == 40
        assert 0 <= summary["mean_return"] <= 40
    assert (seed_dir / "eval.mp4").stat().st_size > 10_000


def test_the_table_lays_runs_out_as_the_papers_table_1(run, tmp_path):
    seed_dir, _ = run
    if not (seed_dir / "eval.json").exists():
        invoke("learn", "eval", seed_dir, "--episodes", 1, "--horizon", 20, "--sim", "ours")
    markdown = tmp_path / "table.md"
    plot = tmp_path / "curves.png"
    invoke("learn", "table", seed_dir.parent, "--markdown", markdown, "--plot", plot)
    text = markdown.read_text()
    assert "| lift (ours) | demo-guided PPO |" in text
    assert "Bin Picking (Can) (paper)" in text and "641 ± 421" in text
    assert "training return at the end" in text and "| demo-guided PPO | lift | 2 | 1 |" in text
    assert plot.stat().st_size > 10_000


def test_the_table_of_plain_robosuites_evaluation_says_so(run, tmp_path):
    seed_dir, _ = run
    if "robosuite" not in json.loads((seed_dir / "eval.json").read_text())["results"]:
        invoke("learn", "eval", seed_dir, "--episodes", 1, "--horizon", 20, "--sim", "robosuite")
    markdown = tmp_path / "table.md"
    invoke("learn", "table", seed_dir.parent, "--sim", "robosuite", "--markdown", markdown)
    text = markdown.read_text()
    assert "| lift (plain robosuite) | demo-guided PPO |" in text and "(ours)" not in text


def test_a_bad_budget_is_named_in_the_error(lift_dataset, tmp_path):
    result = runner.invoke(
        app,
        [
            "learn",
            "rl",
            "--dataset",
            str(lift_dataset),
            "--output",
            str(tmp_path),
            "--budget",
            "lots",
        ],
    )
    assert result.exit_code != 0 and "lots" in result.output


def test_demos_without_a_dataset_are_refused(tmp_path):
    result = runner.invoke(
        app, ["learn", "rl", "--task", "lift", "--demos", "5", "--output", str(tmp_path)]
    )
    assert result.exit_code != 0 and "--dataset" in result.output
