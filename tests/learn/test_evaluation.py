"""The closed-loop evaluation survives a simulator that aborts: MuJoCo can end an episode with a
fatal error (a wild policy once drove plain robosuite to "mj_narrowphase: collision function
returned 10 contacts ... expected at most 8"); that episode ends where it stood, says why, and
the evaluation goes on with the next one."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from crowdteleop.learn.data import dataset_env_args
from crowdteleop.learn.demo_states import load_demo_states
from crowdteleop.learn.envs import EnvSettings, make_env, robosuite_scene
from crowdteleop.learn.evaluation import evaluate

ABORT_AT_CALL = 30  # the 30th physics step of the run: inside the first episode
EPISODE_STEPS = 20


class StillAgent:
    """Asks for no motion: the episodes' course does not depend on a policy."""

    def reset(self, seed: int) -> None:
        pass

    def act(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(7, dtype=np.float32)


@pytest.fixture
def plain_robosuite(lift_dataset):
    sim_config = load_demo_states(lift_dataset).sim_config
    settings = EnvSettings(sim_config=sim_config, horizon=EPISODE_STEPS, demo_reset_p=0.0)
    scene = robosuite_scene(dataset_env_args(lift_dataset))
    env = make_env(settings, sim="robosuite", scene=scene)
    yield env
    env.close()


@pytest.fixture
def aborting_mujoco(monkeypatch):
    """MuJoCo's own stepping (robosuite's lite physics calls mj_step1 / mj_step2, else
    mj_step), except that one call raises MuJoCo's fatal error, as the contact overflow did
    (collisions run in mj_step1)."""
    calls = [0]

    def aborting(real):
        def step(*args, **kwargs):
            calls[0] += 1
            if calls[0] == ABORT_AT_CALL:
                raise mujoco.FatalError("mj_narrowphase: collision function returned 10 contacts")
            return real(*args, **kwargs)

        return step

    for name in ("mj_step", "mj_step1"):
        monkeypatch.setattr(mujoco, name, aborting(getattr(mujoco, name)))


def test_an_episode_the_simulator_aborts_ends_there_and_the_next_ones_run(
    plain_robosuite, aborting_mujoco
):
    report = evaluate(StillAgent(), plain_robosuite, seeds=[7, 8, 9])

    aborted, *rest = report.episodes
    assert aborted.error is not None and "collision function" in aborted.error
    assert 0 < aborted.steps < EPISODE_STEPS
    assert not aborted.success
    assert [e.steps for e in rest] == [EPISODE_STEPS, EPISODE_STEPS]
    assert all(e.error is None for e in rest)
    assert report.errors == [f"seed 7, step {aborted.steps}: {aborted.error}"]


def test_the_summary_counts_aborted_episodes_and_says_why(plain_robosuite, aborting_mujoco):
    summary = evaluate(StillAgent(), plain_robosuite, seeds=[7, 8]).summary()

    assert summary["episodes"] == 2 and summary["simulator_errors"] == 1
    first, second = summary["per_episode"]
    assert "collision function" in first["error"]
    assert "error" not in second
