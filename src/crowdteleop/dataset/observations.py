"""robomimic's ``obs`` / ``next_obs`` from recorded states, on the platform's own simulation.

What robomimic's ``dataset_states_to_obs.py`` does with plain robosuite (reset to each state,
read the observables; step the last action for the last ``next_obs``), done on the fast path:
the observables are robosuite's own sensors evaluated on our MuJoCo data
(`Simulation.observations`), so keys, shapes and values are robosuite's
(``tests/dataset/test_observations.py`` checks them against plain robosuite's).

One pass per demo also yields the controller state before every step (robosuite's ramped
finger command), which restoring a step exactly needs beside the state, and where the hand was
after the last action.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from crowdteleop.dataset.files import DatasetError
from crowdteleop.dataset.replay import Demo, ReplayChecker
from crowdteleop.recording.episode_file import StepLabels

LOW_DIM = "low-dim"
_RGB = re.compile(r"^rgb:(?P<camera>[\w-]+):(?P<width>\d+)x(?P<height>\d+)$")


@dataclass(frozen=True)
class ImageSpec:
    camera: str
    width: int
    height: int

    @property
    def key(self) -> str:
        """robomimic's key for a camera's images."""
        return f"{self.camera}_image"


@dataclass(frozen=True)
class ObsSpec:
    """What ``--obs`` asked for: low-dim keys and/or camera images."""

    low_dim: bool
    images: tuple[ImageSpec, ...]

    @property
    def empty(self) -> bool:
        return not self.low_dim and not self.images


def parse_obs(items: Sequence[str]) -> ObsSpec:
    """``["low-dim", "rgb:agentview:84x84"]`` (comma-separated items allowed) -> ObsSpec;
    ``["none"]`` writes no observations."""
    parts = [p.strip() for item in items for p in item.split(",") if p.strip()]
    low_dim, images = False, []
    for part in parts:
        if part == LOW_DIM:
            low_dim = True
        elif part == "none":
            continue
        elif match := _RGB.match(part):
            width, height = int(match["width"]), int(match["height"])
            if not (8 <= width <= 1024 and 8 <= height <= 1024):
                raise DatasetError(f"--obs {part}: image sizes go from 8 to 1024 pixels")
            images.append(ImageSpec(match["camera"], width, height))
        else:
            raise DatasetError(
                f"--obs {part!r}: expected 'low-dim', 'rgb:CAMERA:WxH' (e.g. rgb:agentview:84x84) "
                "or 'none'"
            )
    return ObsSpec(low_dim, tuple(images))


@dataclass(frozen=True)
class DemoPass:
    """Everything one pass over a demo's states computes."""

    obs: dict[str, npt.NDArray[np.generic]]  # key -> (N, ...)
    next_obs: dict[str, npt.NDArray[np.generic]]
    controller_states: npt.NDArray[np.float64]  # (N, k): before each step
    hand_after_last: npt.NDArray[np.float64]  # (3,)
    labels: list[StepLabels]  # each state's subtask labels, for a recording made without


def observe_demo(
    checker: ReplayChecker,
    demo: Demo,
    spec: ObsSpec,
    tick: Callable[[], None] | None = None,
) -> DemoPass:
    """Set each recorded state and observe it; step each action from its recorded state (and
    controller state) to learn the next controller state; the last action's outcome is the
    last ``next_obs``, as in robomimic's conversion."""
    sim = checker.start(demo)
    if spec.images:
        unknown = sorted({i.camera for i in spec.images} - set(sim.cameras))
        if unknown:
            raise DatasetError(
                f"camera {', '.join(unknown)} is not in this scene; it has {', '.join(sim.cameras)}"
            )
    rows: dict[str, list[npt.NDArray[np.generic]]] = {}
    controller = [sim.controller_state()]
    labels: list[StepLabels] = []

    def observe() -> None:
        if spec.low_dim:
            for key, value in sim.observations().items():
                rows.setdefault(key, []).append(value)
        for image in spec.images:
            frame = sim.render(image.camera, image.width, image.height)
            rows.setdefault(image.key, []).append(frame.copy())

    for state, action in zip(demo.states, demo.actions, strict=True):
        sim.set_state(state)
        sim.set_controller_state(controller[-1])
        observe()
        labels.append(StepLabels.read(sim))
        sim.step(action)
        controller.append(sim.controller_state())
        if tick is not None:
            tick()
    hand_after_last = sim.robot_state().end_effector.position.copy()
    observe()  # after the last action: the last next_obs
    stacked = {key: np.stack(values) for key, values in rows.items()}
    return DemoPass(
        obs={key: values[:-1] for key, values in stacked.items()},
        next_obs={key: values[1:] for key, values in stacked.items()},
        controller_states=np.array(controller[:-1], dtype=np.float64),
        hand_after_last=hand_after_last,
        labels=labels,
    )


def write_demo_pass(group: Any, computed: DemoPass, actions_abs: Any | None) -> None:
    """Into ``data/demo_k``: ``obs/``, ``next_obs/``, ``controller_states`` and, for robosuite
    scenes, ``actions_abs`` (robomimic's layout; images uint8 HxWx3, gzip'd)."""
    for folder, values in (("obs", computed.obs), ("next_obs", computed.next_obs)):
        for key, array in values.items():
            if array.dtype == np.uint8:
                group.create_dataset(f"{folder}/{key}", data=array, compression="gzip")
            else:
                group.create_dataset(f"{folder}/{key}", data=array)
    group.create_dataset("controller_states", data=computed.controller_states)
    if actions_abs is not None:
        group.create_dataset("actions_abs", data=actions_abs)
