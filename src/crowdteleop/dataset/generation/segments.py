"""A labelled demo cut into subtask segments, MimicGen's unit of reuse.

A subtask is a (stage, object) label in the order the demo first reaches it: lift's are
("reach", cube) then ("grasped", cube); pick-place-can's ("reach", Can) then ("grasped",
Can/target). Segment k runs from the step its label first appears to the step the next one
does; the last runs to the demo's end (its success steps included). The "done" label and a
stage relative to no object start no subtask.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from crowdteleop.dataset.files import DatasetError
from crowdteleop.dataset.generation.labels import DemoLabels, first_appearances
from crowdteleop.dataset.generation.poses import Matrix


@dataclass(frozen=True)
class Subtask:
    stage: str
    relative_to: str  # the object whose frame the segment moves with

    def __str__(self) -> str:
        return f"{self.stage} ({self.relative_to})"


@dataclass(frozen=True)
class Segment:
    """One subtask of one source demo: its absolute targets and gripper actions, and where its
    object was when it began."""

    demo: str
    subtask: Subtask
    start: int
    end: int  # exclusive
    targets: Matrix  # (n, 4, 4) world
    gripper: npt.NDArray[np.float64]  # (n,)
    object_at_start: Matrix  # (4, 4)


def subtasks_of(labels: DemoLabels) -> list[tuple[Subtask, int]]:
    """(subtask, first step) in the order the demo reached them."""
    return [
        (Subtask(stage, rel), start)
        for stage, rel, start in first_appearances(labels.stage, labels.relative_to)
        if stage != "done" and rel
    ]


def segments_of(labels: DemoLabels) -> list[Segment]:
    """The demo's segments, one per subtask (see the module's docstring)."""
    order = subtasks_of(labels)
    steps = len(labels.stage)
    segments = []
    for k, (subtask, start) in enumerate(order):
        end = order[k + 1][1] if k + 1 < len(order) else steps
        if subtask.relative_to not in labels.objects:
            raise DatasetError(
                f"{labels.name}: stage {subtask.stage!r} is relative to "
                f"{subtask.relative_to!r}, which its labels hold no pose of"
            )
        segments.append(
            Segment(
                labels.name,
                subtask,
                start,
                end,
                labels.targets[start:end],
                labels.gripper[start:end],
                labels.objects[subtask.relative_to][start],
            )
        )
    return segments


def common_subtasks(
    demos: list[DemoLabels],
) -> tuple[list[Subtask], list[list[Segment]], list[str]]:
    """The subtask sequence most sources share, their segments, and the demos left out (with
    why): generation stitches segment k of one source after segment k-1 of another only when
    both mean the same subtask."""
    cut = {demo.name: segments_of(demo) for demo in demos}
    sequences = [tuple(seg.subtask for seg in segments) for segments in cut.values()]
    sequences = [seq for seq in sequences if seq]
    if not sequences:
        raise DatasetError(
            "no source demo has a subtask (a stage relative to an object): the task declares no "
            "stages generation can follow (docs/generation.md says how a task declares them)"
        )
    common = max(set(sequences), key=sequences.count)
    kept, left_out = [], []
    for name, segments in cut.items():
        if tuple(seg.subtask for seg in segments) == common:
            kept.append(segments)
        else:
            sequence = " -> ".join(str(seg.subtask) for seg in segments) or "none"
            left_out.append(f"{name}: subtasks {sequence}")
    return list(common), kept, left_out
