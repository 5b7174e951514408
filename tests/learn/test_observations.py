"""A BC policy may see quaternions as 6D rotations: q and -q (one pose, robosuite's sign flip
where w passes 0) become one input, and robosuite says which entries of ``object`` they are."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from crowdteleop.learn.bc import Policy, load_checkpoint, train_bc
from crowdteleop.learn.config import STOCK_OBS_KEYS, BCConfig
from crowdteleop.learn.data import LearnDataError, load_learn_data
from crowdteleop.learn.envs import robosuite_scene
from crowdteleop.learn.observations import ObservationForm, observation_form

LIFT_DIMS = (3, 4, 2, 10)  # eef pos, eef quat, finger joints, cube pos + quat + to-hand pos


def test_a_quaternion_and_its_negation_are_one_input():
    quats = Rotation.random(20, random_state=0).as_quat()  # (x, y, z, w)
    before, after = np.full((20, 2), 7.0), np.full((20, 3), -5.0)
    form = ObservationForm(raw_dim=9, quaternions=(2,))
    seen = form.apply(np.concatenate([before, quats, after], axis=1))
    flipped = form.apply(np.concatenate([before, -quats, after], axis=1))
    assert seen.shape == (20, 11) and form.learned_dim == 11
    np.testing.assert_allclose(seen, flipped)
    np.testing.assert_array_equal(seen[:, :2], before)
    np.testing.assert_array_equal(seen[:, 8:], after)
    matrices = Rotation.from_quat(quats).as_matrix()
    np.testing.assert_allclose(seen[:, 2:5], matrices[:, :, 0])  # the first column
    np.testing.assert_allclose(seen[:, 5:8], matrices[:, :, 1])  # then the second


def test_the_recorded_form_passes_observations_through():
    raw = np.random.default_rng(1).normal(size=(4, 19))
    form = observation_form("quaternion", STOCK_OBS_KEYS, LIFT_DIMS, None)
    np.testing.assert_array_equal(form.apply(raw), raw)
    with pytest.raises(ValueError, match="size 18"):
        form.apply(raw[:, 1:])


def test_robosuite_names_the_quaternions_inside_object(lift_dataset):
    data = load_learn_data(lift_dataset, STOCK_OBS_KEYS)
    scene = robosuite_scene(data.env_args)
    form = observation_form("6d", STOCK_OBS_KEYS, data.obs_dims, scene)
    assert form.quaternions == (3, 9 + 3)  # the hand's, then the cube's after its position
    with pytest.raises(LearnDataError, match="cannot tell which"):
        observation_form("6d", STOCK_OBS_KEYS, (3, 4, 2, 11), scene)
    with pytest.raises(LearnDataError, match="env_args"):
        observation_form("6d", STOCK_OBS_KEYS, data.obs_dims, None)


def test_a_6d_policy_acts_on_recorded_observations_and_ignores_the_sign(lift_dataset, tmp_path):
    config = BCConfig(
        epochs=1, head="deterministic", obs_rotation="6d", hidden_dim=32, steps_per_epoch=5
    )
    checkpoint = load_checkpoint(train_bc(lift_dataset, tmp_path, config).checkpoint)
    assert checkpoint.form.quaternions == (3, 12)
    assert checkpoint.norm.obs_mean.shape == (19 + 2 * 2,)
    row = load_learn_data(lift_dataset, STOCK_OBS_KEYS).train[0].obs[5]
    flipped = row.copy()
    flipped[3:7] *= -1
    flipped[12:16] *= -1
    policy = Policy(checkpoint)
    policy.reset()
    action = policy.act(row)
    policy.reset()
    np.testing.assert_allclose(policy.act(flipped), action, atol=1e-6)
