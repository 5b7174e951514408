"""Absolute targets are learned in a continuous form and come back as the recorded layout."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from crowdteleop.learn.actions import from_learned, to_learned


def absolute_rows(rotvecs: np.ndarray) -> np.ndarray:
    n = len(rotvecs)
    return np.concatenate([np.full((n, 3), 0.4), rotvecs, np.ones((n, 1))], axis=1)


def test_deltas_are_learned_as_they_are():
    rows = np.random.default_rng(0).uniform(-1, 1, (5, 7))
    np.testing.assert_array_equal(to_learned(rows, "actions"), rows)
    np.testing.assert_array_equal(from_learned(rows[0], "actions"), rows[0])


def test_absolute_targets_round_trip_through_the_learned_form():
    rotvecs = Rotation.random(50, random_state=1).as_rotvec()
    rows = absolute_rows(rotvecs)
    learned = to_learned(rows, "actions_abs")
    assert learned.shape == (50, 10)
    back = np.array([from_learned(row, "actions_abs") for row in learned])
    np.testing.assert_allclose(back[:, :3], rows[:, :3])
    np.testing.assert_allclose(back[:, 6], rows[:, 6])
    turned = Rotation.from_rotvec(back[:, 3:6]) * Rotation.from_rotvec(rotvecs).inv()
    assert np.max(turned.magnitude()) < 1e-9


def test_a_hand_pointing_down_has_one_learned_form_where_its_axis_angle_flips():
    """+pi x and -pi x are one pose: the learned form is the same, so a policy need not jump."""
    a, b = np.array([[np.pi - 1e-6, 0, 0]]), np.array([[-(np.pi - 1e-6), 0, 0]])
    learned_a, learned_b = (
        to_learned(absolute_rows(a), "actions_abs"),
        to_learned(absolute_rows(b), "actions_abs"),
    )
    np.testing.assert_allclose(learned_a, learned_b, atol=1e-5)


def test_a_policy_output_off_the_rotation_manifold_still_gives_a_rotation():
    row = np.array([0.4, 0.0, 0.1, 0.9, 0.1, 0.0, 0.2, 0.8, 0.1, -1.0])
    out = from_learned(row, "actions_abs")
    assert out.shape == (7,) and np.all(np.isfinite(out))
    assert out[6] == -1.0
