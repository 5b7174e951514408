"""Demonstrations as SAC's transitions (learn.demo_buffer): each demo cut at its first solved
step, rewarded and ended there, as a training episode is; and batches drawn half from them
once the run has experience of its own, all from them before."""

from __future__ import annotations

import h5py
import numpy as np
import pytest
from gymnasium import spaces

from crowdteleop.learn.config import STOCK_OBS_KEYS
from crowdteleop.learn.data import LearnDataError
from crowdteleop.learn.demo_buffer import DemoReplayBuffer, load_demo_transitions


def test_each_demo_ends_at_its_first_solved_step_with_the_reward(lift_dataset):
    transitions = load_demo_transitions(lift_dataset, 2, STOCK_OBS_KEYS)
    with h5py.File(lift_dataset) as file:
        firsts = [int(np.argmax(file[f"data/demo_{k}/rewards"][()] > 0)) + 1 for k in (1, 2)]
        first_obs = file["data/demo_1/obs/robot0_eef_pos"][0]
    assert len(transitions) == sum(firsts) and transitions.demos == 2
    assert transitions.rewards.sum() == 2 and transitions.dones.sum() == 2
    assert transitions.rewards[firsts[0] - 1] == 1 and transitions.rewards[-1] == 1
    assert transitions.obs.shape == transitions.next_obs.shape == (len(transitions), 19)
    np.testing.assert_allclose(transitions.obs[0, :3], first_obs, rtol=1e-6)
    np.testing.assert_array_equal(transitions.obs[1], transitions.next_obs[0])
    assert np.abs(transitions.actions).max() <= 1.0


def test_more_demos_than_the_dataset_holds_are_refused(lift_dataset):
    with pytest.raises(LearnDataError, match="holds 3 demonstrations; 5 were asked"):
        load_demo_transitions(lift_dataset, 5, STOCK_OBS_KEYS)


def test_a_dataset_without_observations_names_the_build_that_adds_them(lift_dataset, tmp_path):
    bare = tmp_path / "bare.hdf5"
    with h5py.File(lift_dataset) as source, h5py.File(bare, "w") as target:
        for name in source["data"]:
            group = target.create_group(f"data/{name}")
            for key in ("states", "actions", "rewards", "dones"):
                group[key] = source[f"data/{name}/{key}"][()]
    with pytest.raises(LearnDataError, match=r"no 'obs'.*dataset build .* --obs low-dim"):
        load_demo_transitions(bare, 1, STOCK_OBS_KEYS)


def _buffer(lift_dataset, fraction: float) -> DemoReplayBuffer:
    demos = load_demo_transitions(lift_dataset, 2, STOCK_OBS_KEYS)
    observation = spaces.Box(-np.inf, np.inf, (19,), np.float32)
    action = spaces.Box(-1, 1, (7,), np.float32)
    buffer = DemoReplayBuffer(100, observation, action, device="cpu")
    buffer.attach(demos, fraction, seed=0)
    return buffer


def test_batches_are_all_demos_until_the_run_has_its_own_then_the_fraction(lift_dataset):
    buffer = _buffer(lift_dataset, 0.25)
    demo_obs = {tuple(row) for row in buffer.demos.obs}
    before = buffer.sample(64)
    assert all(tuple(row) in demo_obs for row in before.observations.numpy())
    own = np.full((1, 19), 7.0, np.float32)
    for _ in range(10):
        buffer.add(own, own, np.zeros((1, 7), np.float32), np.zeros(1), np.zeros(1), [{}])
    after = buffer.sample(64)
    from_run = (after.observations.numpy() == 7.0).all(axis=1).sum()
    assert from_run == 48, "a quarter from the demos, the rest from the run's experience"
    assert after.rewards.shape == after.dones.shape == (64, 1)
