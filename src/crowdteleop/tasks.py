"""Named tasks. Each entry says which backend builds it and what the worker must do."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from crowdteleop.errors import UnknownTaskError

Backend = Literal["robosuite", "mujoco"]


@dataclass(frozen=True)
class TaskSpec:
    name: str
    backend: Backend
    env_name: str  # robosuite environment class, or the scene name for the mujoco backend
    instruction: str
    default_camera: str = "frontview"
    time_limit_s: float = 120.0
    env_kwargs: dict[str, Any] = field(default_factory=dict)


_TASKS: tuple[TaskSpec, ...] = (
    TaskSpec(
        "lift",
        "robosuite",
        "Lift",
        "Pick up the red cube and lift it above the table.",
        time_limit_s=60.0,
    ),
    TaskSpec(
        "pick-place",
        "robosuite",
        "PickPlace",
        "Put the milk, bread, cereal and can each into its own bin.",
        time_limit_s=300.0,
    ),
    TaskSpec(
        "pick-place-can",
        "robosuite",
        "PickPlaceCan",
        "Pick up the can and place it into its bin (bottom right).",
    ),
    TaskSpec(
        "nut-assembly",
        "robosuite",
        "NutAssembly",
        "Fit the square nut onto the square peg and the round nut onto the round peg.",
        time_limit_s=300.0,
    ),
    TaskSpec(
        "nut-assembly-round",
        "robosuite",
        "NutAssemblyRound",
        "Fit the round nut onto the round peg.",
    ),
    TaskSpec(
        "mujoco-lift",
        "mujoco",
        "lift",
        "Pick up the red cube and lift it above the table (pure-MuJoCo scene, no robosuite).",
        time_limit_s=60.0,
    ),
)
TASKS: dict[str, TaskSpec] = {task.name: task for task in _TASKS}


def get_task(name: str) -> TaskSpec:
    try:
        return TASKS[name]
    except KeyError:
        raise UnknownTaskError(
            f"unknown task {name!r}; choose one of: {', '.join(TASKS)}"
        ) from None
