"""Scripted episodes carry subtask labels that describe each row's state, as an offline pass
that sets the state and asks the simulation would compute them."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig
from crowdteleop.recording.episode_file import read_episode


def flat(pose) -> np.ndarray:
    return np.concatenate([pose.position, pose.quaternion])


def test_a_scripted_lift_episode_is_labelled_state_by_state(tmp_path):
    with scripted_rig("lift") as rig:
        episode = read_episode(record_scripted_episode(rig, tmp_path, "lift-0", seed=0).path)
        labels = episode.labels
        assert episode.outcome == "success" and labels is not None
        assert len(labels.stage) == len(labels.relative_to) == episode.steps
        assert labels.hand_pose.shape == (episode.steps, 7)
        assert [stage for stage, _ in itertools.groupby(labels.stage)] == [
            "reach",
            "grasped",
            "done",
        ]
        for stage, relative_to in zip(labels.stage, labels.relative_to, strict=True):
            assert relative_to == {"reach": "cube", "grasped": "cube", "done": ""}[stage]
        assert set(labels.object_poses) == set(rig.sim.object_poses())

        sim = rig.sim
        steps = episode.steps
        first_grasped = labels.stage.index("grasped")
        for t in sorted({0, 1, first_grasped - 1, first_grasped, steps // 2, steps - 1}):
            sim.set_state(episode.states[t])  # the offline pass: state t, then ask the sim
            progress = sim.progress()
            assert (labels.stage[t], labels.relative_to[t]) == (
                progress.stage,
                progress.relative_to,
            ), t
            hand = flat(sim.robot_state().end_effector)
            np.testing.assert_allclose(labels.hand_pose[t], hand, rtol=0, atol=1e-9)
            for name, pose in sim.object_poses().items():
                np.testing.assert_allclose(
                    labels.object_poses[name][t], flat(pose), rtol=0, atol=1e-9
                )


@pytest.mark.parametrize("task", ["pick-place-can"])
def test_object_names_with_a_slash_survive_the_episode_file(tmp_path, task):
    with scripted_rig(task) as rig:
        scripted = record_scripted_episode(rig, tmp_path, "can", seed=0, time_limit_s=1.0)
        episode = read_episode(scripted.path)
        labels = episode.labels
        assert labels is not None
        assert labels.stage[0] == "reach" and labels.relative_to[0] == "Can"
        assert "Can/target" in labels.object_poses
        rig.sim.set_state(episode.states[-1])
        target = rig.sim.object_poses()["Can/target"]
        np.testing.assert_allclose(labels.object_poses["Can/target"][-1], flat(target), atol=1e-9)
        assert scripted.recorder.notes == 0
