"""Subtask labels: per step, the task's stage, the object that stage is relative to, the hand's
pose and every object's pose; written into a dataset as ``datagen_info`` (MimicGen's group name
and keys, plus ours) and read back by generation.

Labels are a function of the state: the teleop server records them as it runs
(`crowdteleop.recording.episode_file.StepLabels`), and ``dataset build`` computes them from the
states of a recording made before they existed (`StepLabels.read` on each state it sets).

``data/demo_k/datagen_info`` (docs/dataset.md):

- ``eef_pose`` (N, 4, 4): the hand (the controller's end-effector site), world frame;
- ``target_pose`` (N, 4, 4): the absolute OSC target each action set (``actions_abs``), world
  frame; ``gripper_action`` (N, 1): the action's gripper entry;
- ``object_poses/<name>`` (N, 4, 4): each object; a "/" in a name ("Can/target", the can's
  goal) is written "::";
- ``stage``, ``relative_to`` (N,): the labels as strings;
- ``subtask_term_signals/<stage>`` (N,): 1 from the step the next stage first begins, MimicGen's
  subtask-end signals.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import h5py
import numpy as np
import numpy.typing as npt

from crowdteleop.dataset.files import DatasetError
from crowdteleop.dataset.generation.poses import Matrix, from_pose7, from_target
from crowdteleop.recording.episode_file import EpisodeLabels, StepLabels

GROUP = "datagen_info"
NAME_SLASH = "::"  # "/" in an object's name, inside an HDF5 path


def stack_labels(steps: list[StepLabels]) -> EpisodeLabels:
    """One demo's labels as arrays (an object missing at a step: NaN)."""
    names = sorted({name for step in steps for name in step.object_poses})
    nan = np.full(7, np.nan)
    return EpisodeLabels(
        stage=[step.stage for step in steps],
        relative_to=[step.relative_to for step in steps],
        hand_pose=np.array([step.hand_pose for step in steps], dtype=np.float64),
        object_poses={
            name: np.array([step.object_poses.get(name, nan) for step in steps], dtype=np.float64)
            for name in names
        },
    )


def first_appearances(stages: list[str], relative_to: list[str]) -> list[tuple[str, str, int]]:
    """(stage, relative_to, first step) of each label in the order it first appears: a stage
    left and re-entered (a grasp lost for a step) counts where it began."""
    seen: dict[tuple[str, str], int] = {}
    for index, label in enumerate(zip(stages, relative_to, strict=True)):
        seen.setdefault(label, index)
    return [(stage, rel, index) for (stage, rel), index in seen.items()]


def write_datagen_info(
    group: h5py.Group,
    labels: EpisodeLabels,
    actions: npt.NDArray[np.float64],
    targets_world: Matrix | None,
) -> None:
    """``datagen_info`` into a demo's group (see the module's docstring)."""
    info = group.create_group(GROUP)
    info.create_dataset("eef_pose", data=from_pose7(labels.hand_pose))
    if targets_world is not None:
        info.create_dataset("target_pose", data=targets_world)
    info.create_dataset("gripper_action", data=np.asarray(actions)[:, -1:])
    for name, poses in labels.object_poses.items():
        info.create_dataset(f"object_poses/{name.replace('/', NAME_SLASH)}", data=from_pose7(poses))
    strings = h5py.string_dtype()
    info.create_dataset("stage", data=np.array(labels.stage, dtype=object), dtype=strings)
    info.create_dataset(
        "relative_to", data=np.array(labels.relative_to, dtype=object), dtype=strings
    )
    order = first_appearances(labels.stage, labels.relative_to)
    steps = len(labels.stage)
    for (stage, _, _), (_, _, next_start) in itertools.pairwise(order):
        signal = np.zeros(steps, dtype=np.int64)
        signal[next_start:] = 1
        info.create_dataset(f"subtask_term_signals/{stage}", data=signal)


@dataclass(frozen=True)
class DemoLabels:
    """What generation reads of one source demo."""

    name: str
    stage: list[str]
    relative_to: list[str]
    targets: Matrix  # (N, 4, 4) world
    gripper: npt.NDArray[np.float64]  # (N,)
    objects: dict[str, Matrix]  # name -> (N, 4, 4)


def read_datagen_info(group: h5py.Group, name: str) -> DemoLabels:
    """A demo's labels; a dataset built before labels existed is a clear error."""
    if GROUP not in group or "target_pose" not in group[GROUP]:
        raise DatasetError(
            f"{name} has no subtask labels (datagen_info with target_pose): build the dataset "
            "again with `crowdteleop dataset build` (it labels every demo from its states; "
            "absolute targets need an OSC or IK-velocity recording)"
        )
    info = group[GROUP]
    poses = info.get("object_poses", {})
    objects = {key.replace(NAME_SLASH, "/"): poses[key][()] for key in poses}
    return DemoLabels(
        name=name,
        stage=[s.decode() if isinstance(s, bytes) else str(s) for s in info["stage"][()]],
        relative_to=[
            s.decode() if isinstance(s, bytes) else str(s) for s in info["relative_to"][()]
        ],
        targets=info["target_pose"][()],
        gripper=info["gripper_action"][()][:, 0],
        objects=objects,
    )


def targets_in_world(base_frame: Matrix, actions_abs: npt.NDArray[np.float64]) -> Matrix:
    """(N, 4, 4) world poses of absolute targets given in the arm base's frame."""
    return np.asarray(base_frame @ from_target(actions_abs[:, :6]))
