"""Subtask labels (stage, relative_to, hand and object poses) through the log and the file."""

from __future__ import annotations

import dataclasses
import os
from types import SimpleNamespace

import h5py
import numpy as np
import pytest

from crowdteleop.recording.episode_file import (
    InvalidRecordError,
    StepLabels,
    StepRecord,
    read_episode,
)
from crowdteleop.recording.wal import EpisodeRecorder
from crowdteleop.recording.wal_reader import read_partial
from crowdteleop.recording.wal_recovery import recover_orphans
from tests.fixtures import recording_child as child

NAN7 = np.full(7, np.nan)


def pose(seed: float) -> np.ndarray:
    return np.array([seed, -seed, 0.5 * seed, 0.0, 0.0, np.sin(seed), np.cos(seed)])


def labels(index: int, names=("cube", "Can/target", "table")) -> StepLabels:
    stage = ("reach", "grasped", "done")[min(index // 3, 2)]
    return StepLabels(
        stage=stage,
        relative_to="" if stage == "done" else names[0],
        hand_pose=pose(index + 0.25),
        object_poses={name: pose(index + k) for k, name in enumerate(names)},
    )


def labelled(index: int, step_labels: StepLabels | None) -> StepRecord:
    return dataclasses.replace(child.make_step(index), labels=step_labels)


def recorder_of(directory, episode_id: str, steps: list[StepRecord], **kwargs) -> EpisodeRecorder:
    kwargs.setdefault("flush_interval_s", 0.0)  # every step durable: read_partial sees it
    recorder = EpisodeRecorder(directory, episode_id, {"task": "lift"}, **kwargs)
    for step in steps:
        recorder.append(step)
    return recorder


def assert_labels_equal(got, expected: list[StepLabels | None]) -> None:
    """``got`` (EpisodeLabels) holds ``expected`` step by step; None: "" and NaN rows."""
    assert got is not None
    assert got.stage == [s.stage if s else "" for s in expected]
    assert got.relative_to == [s.relative_to if s else "" for s in expected]
    np.testing.assert_array_equal(
        got.hand_pose, np.array([s.hand_pose if s else NAN7 for s in expected])
    )
    names = {name: None for s in expected if s for name in s.object_poses}
    assert list(got.object_poses) == list(names)
    for name in names:
        rows = [s.object_poses.get(name, NAN7) if s else NAN7 for s in expected]
        np.testing.assert_array_equal(got.object_poses[name], np.array(rows))


def test_labels_round_trip_through_the_log_and_the_file(tmp_path):
    expected = [labels(i) for i in range(9)]
    recorder = recorder_of(tmp_path, "labelled", [labelled(i, s) for i, s in enumerate(expected)])
    assert_labels_equal(read_partial(recorder.wal_path).labels, expected)
    episode = read_episode(recorder.finalize("success"))
    assert_labels_equal(episode.labels, expected)
    assert recorder.notes == 0
    with h5py.File(tmp_path / "labelled.hdf5", "r") as file:  # the layout docs/recording.md gives
        group = file["data/demo_0/labels"]
        assert group["stage"].asstr()[()].tolist()[:4] == ["reach"] * 3 + ["grasped"]
        assert group["hand_pose"].shape == (9, 7) and group["hand_pose"].dtype == np.float64
        objects = group["object_poses"]
        assert list(objects) == ["cube", "Can%2Ftarget", "table"]  # in recorded order
        assert objects["Can%2Ftarget"].attrs["name"] == "Can/target"
        assert objects["Can%2Ftarget"].shape == (9, 7)


def test_mixed_steps_and_objects_that_come_and_go_read_as_empty_and_nan(tmp_path):
    odd_names = ("Can/target", "é/ü", "50%", "a.b", "..", " spaced ")
    expected: list[StepLabels | None] = [
        None,  # a step recorded without labels
        labels(1, names=("cube",)),
        labels(2, names=odd_names),
        None,
        labels(4, names=("table", "cube")),
        StepLabels("", "", pose(5.0), {}),  # labels without objects
    ]
    recorder = recorder_of(tmp_path, "mixed", [labelled(i, s) for i, s in enumerate(expected)])
    episode = read_episode(recorder.finalize("reset"))
    assert_labels_equal(episode.labels, expected)
    assert set(episode.labels.object_poses) == {"cube", "table", *odd_names}
    assert recorder.notes == 0


def test_recordings_without_labels_read_with_labels_none(tmp_path):
    recorder = recorder_of(tmp_path, "plain", [child.make_step(i) for i in range(4)])
    assert read_partial(recorder.wal_path).labels is None
    path = recorder.finalize("success")
    assert read_episode(path).labels is None
    with h5py.File(path, "r") as file:
        assert "labels" not in file["data/demo_0"]  # files as written before labels existed


def test_an_unlabelled_step_is_packed_exactly_as_before_labels(tmp_path):
    """A log without labels never sets the labels flag: older readers and logs agree."""
    plain = recorder_of(tmp_path, "a", [child.make_step(i) for i in range(3)], flush_interval_s=0)
    with_labels = recorder_of(
        tmp_path, "b", [labelled(i, labels(i)) for i in range(3)], flush_interval_s=0
    )
    plain_log, labelled_log = plain.wal_path.read_bytes(), with_labels.wal_path.read_bytes()
    assert b"reach" in labelled_log and b"reach" not in plain_log
    plain.close()
    with_labels.close()


def test_a_crashed_recording_keeps_its_labels(tmp_path):
    expected = [labels(i) for i in range(7)]
    steps = [labelled(i, s) for i, s in enumerate(expected)]
    recorder = recorder_of(tmp_path, "crashed", steps[:6], flush_interval_s=0.0)
    six_steps = recorder.wal_path.stat().st_size
    recorder.append(steps[6])
    recorder.close()  # as if the process died after its last flush
    # ... with the last step torn mid-write: dropped, the rest recovered with their labels
    os.truncate(tmp_path / "crashed.wal", six_steps + 30)

    assert recover_orphans(tmp_path) == [tmp_path / "crashed.hdf5"]
    episode = read_episode(tmp_path / "crashed.hdf5")
    assert (episode.outcome, episode.recovered, episode.steps) == ("crash", True, 6)
    assert_labels_equal(episode.labels, expected[:6])


def test_bad_labels_are_refused_on_append_and_the_recorder_keeps_working(tmp_path):
    recorder = recorder_of(tmp_path, "bad", [labelled(0, labels(0))])
    good = labels(1)
    bad_labels = [
        dataclasses.replace(good, hand_pose=np.zeros(6)),  # wrong shape
        dataclasses.replace(good, hand_pose=np.zeros((1, 7))),
        dataclasses.replace(good, hand_pose=[0.0] * 7),  # not an array
        dataclasses.replace(good, hand_pose=np.zeros(7, dtype=np.float32)),
        dataclasses.replace(good, object_poses={"cube": np.zeros(3)}),
        dataclasses.replace(good, object_poses={1: np.zeros(7)}),  # a name that is not a str
        dataclasses.replace(good, object_poses=[("cube", np.zeros(7))]),
        dataclasses.replace(good, stage=None),
        {"stage": "reach"},  # not a StepLabels
    ]
    for bad in bad_labels:
        with pytest.raises(InvalidRecordError, match="label"):
            recorder.append(labelled(1, bad))
    assert recorder.steps == 1
    recorder.append(labelled(1, good))
    episode = read_episode(recorder.finalize("success"))
    assert_labels_equal(episode.labels, [labels(0), good])


def test_labels_that_cannot_pack_are_stored_as_nan_or_empty_and_counted(tmp_path):
    nan_pose = pose(1.0)
    nan_pose[2] = np.nan
    inf_pose = np.full(7, np.inf)
    odd = StepLabels(
        stage="re\x00ach",  # a NUL: stored as ""
        relative_to="\ud800",  # a lone surrogate: stored as ""
        hand_pose=nan_pose,  # NaN: the whole pose stored as NaN
        object_poses={"cube": inf_pose, "": pose(2.0), ".": pose(3.0), "a\x00b": pose(4.0),
                      "table": pose(5.0)},
    )  # fmt: skip
    recorder = recorder_of(tmp_path, "odd", [labelled(0, odd), labelled(1, labels(1))])
    episode = read_episode(recorder.finalize("success"))
    expected_odd = StepLabels("", "", NAN7, {"cube": NAN7, "table": pose(5.0)})
    assert_labels_equal(episode.labels, [expected_odd, labels(1)])
    assert recorder.notes == 2 + 1 + 1 + 3  # stage and relative_to, hand, cube, three names


def test_step_labels_of_duck_typed_sim_values():
    progress = SimpleNamespace(stage="grasped", relative_to="Can/target", message="...")
    hand = SimpleNamespace(position=np.array([1.0, 2.0, 3.0]), quaternion=np.array([0, 0, 0, 1]))
    can = SimpleNamespace(position=[0.5, 0.0, 0.8], quaternion=(0.0, 0.0, 1.0, 0.0))
    made = StepLabels.of(progress, hand, {"Can/target": can})
    assert (made.stage, made.relative_to) == ("grasped", "Can/target")
    np.testing.assert_array_equal(made.hand_pose, [1, 2, 3, 0, 0, 0, 1])
    np.testing.assert_array_equal(made.object_poses["Can/target"], [0.5, 0, 0.8, 0, 0, 1, 0])
    assert made.hand_pose.dtype == np.float64
    older = SimpleNamespace(stage="reach")  # a TaskProgress from before relative_to
    assert StepLabels.of(older, hand, {}).relative_to == ""
