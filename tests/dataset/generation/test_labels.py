"""Subtask labels in a built dataset (issue 32, item 1): every demo's stage per step, the object
each stage is relative to, the hand, the targets and the objects, as MimicGen's
``datagen_info`` names them; computed from the states where a recording has none."""

from __future__ import annotations

import h5py
import numpy as np

from crowdteleop.dataset.generation.labels import first_appearances, read_datagen_info


def _strings(dataset: h5py.Dataset) -> list[str]:
    return [s.decode() if isinstance(s, bytes) else s for s in dataset[()]]


def test_every_demo_is_labelled_reach_then_grasped_then_done_relative_to_the_cube(lift_sources):
    with h5py.File(lift_sources.dataset, "r") as file:
        for name in file["data"]:
            info = file["data"][name]["datagen_info"]
            stages = _strings(info["stage"])
            order = first_appearances(stages, _strings(info["relative_to"]))
            assert [(stage, rel) for stage, rel, _ in order] == [
                ("reach", "cube"),
                ("grasped", "cube"),
                ("done", ""),
            ]
            grasp_starts = order[1][2]
            signal = info["subtask_term_signals"]["reach"][()]
            assert not signal[:grasp_starts].any() and signal[grasp_starts:].all()
            assert info["eef_pose"].shape == (len(stages), 4, 4)


def test_labels_agree_with_the_observations_robomimic_reads(lift_sources):
    with h5py.File(lift_sources.dataset, "r") as file:
        demo = file["data"]["demo_1"]
        info = demo["datagen_info"]
        np.testing.assert_allclose(info["eef_pose"][:, :3, 3], demo["obs/robot0_eef_pos"][()])
        cube = demo["obs/object"][:, :3]  # robosuite Lift's object-state starts with cube_pos
        np.testing.assert_allclose(info["object_poses/cube"][:, :3, 3], cube)


def test_targets_are_the_goals_the_actions_set_and_the_hand_moves_toward_them(lift_sources):
    labels = _demo_labels(lift_sources.dataset)
    actions = _actions(lift_sources.dataset)
    with h5py.File(lift_sources.dataset, "r") as file:
        hand = file["data"]["demo_1"]["datagen_info"]["eef_pose"][:, :3, 3]
    to_goal = labels.targets[:, :3, 3] - hand
    osc_scale_m = 0.05  # robosuite's OSC_POSE: a delta of 1 asks for 5 cm
    np.testing.assert_allclose(
        np.linalg.norm(to_goal, axis=1),
        np.linalg.norm(actions[:, :3], axis=1) * osc_scale_m,
        atol=1e-9,
    )
    moving = np.linalg.norm(to_goal[:-1], axis=1) > 0.005
    towards = np.sum((hand[1:] - hand[:-1]) * to_goal[:-1], axis=1)[moving] > 0
    assert towards.mean() > 0.85  # a target in the wrong frame: about half, or none
    np.testing.assert_array_equal(labels.gripper, actions[:, -1])


def test_the_can_is_carried_relative_to_its_bin(can_sources):
    labels = _demo_labels(can_sources.dataset)
    order = [(s, r) for s, r, _ in first_appearances(labels.stage, labels.relative_to)]
    assert order[:2] == [("reach", "Can"), ("grasped", "Can/target")]
    assert "Can/target" in labels.objects


def _demo_labels(path):
    with h5py.File(path, "r") as file:
        return read_datagen_info(file["data"]["demo_1"], "demo_1")


def _actions(path):
    with h5py.File(path, "r") as file:
        return file["data"]["demo_1"]["actions"][()]
