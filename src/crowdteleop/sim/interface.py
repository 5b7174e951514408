"""The one interface through which the platform drives a simulated robot.

Nothing backend-specific crosses it: inputs and outputs are numpy arrays and the plain types of
`crowdteleop.sim.types`. A backend owns its simulator, renderer and GL context; `close` frees
them.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from crowdteleop.sim.config import SimConfig
from crowdteleop.sim.types import (
    ActionSpec,
    ContactEvent,
    KinematicModel,
    Marker,
    Pose,
    RobotState,
    StepResult,
    TaskProgress,
)


@runtime_checkable
class Simulation(Protocol):
    config: SimConfig
    action_spec: ActionSpec
    cameras: tuple[str, ...]
    contact_objects: tuple[str, ...]  # what `contacts` can name: the objects, `TABLE_CONTACT`

    @property
    def control_dt(self) -> float:
        """Seconds of simulated time one `step` advances."""
        ...

    def reset(self, seed: int | None = None) -> None:
        """Start a new episode; the same seed gives the same initial state."""

    def step(self, action: npt.NDArray[np.float64]) -> StepResult:
        """Apply `action` (see `action_spec`) for one control period."""
        ...

    def render(
        self, camera: str, width: int, height: int, markers: Sequence[Marker] = ()
    ) -> npt.NDArray[np.uint8]:
        """An RGB frame, uint8 (height, width, 3), top row first; ``markers`` are drawn in
        (visual hints, e.g. a practice round's target: nothing physical)."""
        ...

    def get_state(self) -> npt.NDArray[np.float64]:
        """Flat [time, qpos, qvel]: restoring it reproduces the next step and render exactly."""
        ...

    def set_state(self, state: npt.NDArray[np.float64]) -> None: ...

    def controller_state(self) -> npt.NDArray[np.float64]:
        """What the next step depends on beyond [time, qpos, qvel] and the action: robosuite's
        gripper keeps its finger command between steps and ramps it (shape (1,)); a backend
        without such memory returns shape (0,). Restoring a step exactly sets both."""
        ...

    def set_controller_state(self, value: npt.NDArray[np.float64]) -> None: ...

    def observations(self) -> dict[str, npt.NDArray[np.float64]]:
        """Low-dimensional observations under robomimic's keys (``robot0_eef_pos``,
        ``robot0_eef_quat`` (x, y, z, w), ``robot0_gripper_qpos``, ``object``...), computed
        as plain robosuite computes them, for datasets and policies."""
        ...

    def success(self) -> bool: ...

    def contacts(self) -> list[ContactEvent]: ...
    def progress(self) -> TaskProgress: ...

    def robot_state(self) -> RobotState: ...

    def object_poses(self) -> dict[str, Pose]:
        """Privileged poses of task objects and their grasp frames: for scripted operators and
        analysis only, never sent to workers."""
        ...

    def kinematics(self) -> KinematicModel: ...

    def mjcf_xml(self) -> str: ...

    def close(self) -> None: ...
