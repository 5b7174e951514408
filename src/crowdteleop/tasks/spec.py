"""What a task is: the environment that builds it, what the worker reads, and how it is judged.

A task is plain data, the same whether it is built in or declared by a plug-in (an installed
package's entry point, or a YAML file). Code a task needs (a robosuite environment subclass, a
success test, stage tests) is named by reference, ``"package.module:name"``, and imported only
where a simulator runs: the coordinator and the catalogue never load it.
"""

from __future__ import annotations

import importlib
import importlib.resources
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from pydantic import ConfigDict

from crowdteleop.errors import ConfigError

Backend = Literal["robosuite", "mujoco"]
FastPath = Literal["auto", "on", "off"]

# The single-arm robots robosuite 1.5 ships, each with its default gripper.
ROBOSUITE_ARMS = ("Sawyer", "Panda", "UR5e", "IIWA", "Kinova3", "Jaco")

# The gripper a robot gets where robosuite's default cannot grasp in robosuite 1.5: its
# Robotiq85 (UR5e's, Kinova3's) never closes on an object (robosuite#772), and Jaco's
# three-finger hand closes on -1 at 1% per step with 0.3 N. `SimConfig.gripper` overrides.
PLATFORM_GRIPPERS = {
    "UR5e": "Robotiq140Gripper",
    "Kinova3": "Robotiq140Gripper",
    "Jaco": "Robotiq140Gripper",
}
ROBOSUITE_DEFAULT_GRIPPER = "default"  # `SimConfig.gripper`: robosuite's own choice

NAME_PATTERN = re.compile(r"^[a-z0-9][a-z0-9-]{0,62}$")
REFERENCE_PATTERN = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


@dataclass(frozen=True)
class Stage:
    """One step of a task as the worker sees it: `instruction` shows while the stage is current,
    and the stage is done once `done_when` (a reference to ``f(env) -> bool``) answers True.
    `relative_to` names the object the stage's motion is relative to (a key of the simulation's
    object poses, e.g. "cubeA"): demonstration generation moves the stage with that object."""

    __pydantic_config__ = ConfigDict(extra="forbid")

    name: str
    instruction: str
    done_when: str
    relative_to: str | None = None


@dataclass(frozen=True)
class TaskSpec:
    """A task: `env_name` is a robosuite environment class as robosuite registers it (its own,
    or a subclass the module `env_module` defines) or the scene of the mujoco backend."""

    __pydantic_config__ = ConfigDict(extra="forbid")

    name: str
    backend: Backend
    env_name: str
    instruction: str
    default_camera: str = "frontview"
    time_limit_s: float = 120.0
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    env_module: str | None = None  # imported first: defining the class registers it
    robots: tuple[str, ...] = ()  # robots that fit the task; empty: any single arm
    success: str | None = None  # reference to f(env) -> bool; default: robosuite's own
    stages: tuple[Stage, ...] = ()
    fast_path: FastPath = "auto"  # "auto": the fast path where its checks say it is faithful
    # How the scripted operator (bots, tests) does it: a built-in plan's name ("lift",
    # "pick-place", "nut-assembly", "stack") or a reference to a plan of the task's own.
    operator_plan: str | None = None
    # The objects of a plain-MuJoCo task (backend "mujoco"): an MJCF file whose <worldbody>
    # bodies (and <asset>s) join the platform's arm and table; a path, or "package:file.xml"
    # inside an installed package. Its `success` (and stages) take a `MujocoScene`.
    scene: str | None = None
    # Objects a turn about their own vertical (z) axis leaves the same: how many turns make a
    # full one (4: a cube; 0: any turn, a cylinder). Demonstration generation grasps such an
    # object the way its source did instead of spinning the hand by a turn that changes nothing.
    symmetric_objects: dict[str, int] = field(default_factory=dict)
    source: str = "built-in"  # where the declaration came from, for listings and errors

    def __post_init__(self) -> None:
        problems = declaration_problems(self)
        if problems:
            raise ConfigError(f"task {self.name!r} ({self.source}): " + "; ".join(problems))


def declaration_problems(task: TaskSpec) -> list[str]:
    """What is wrong with a declaration, in words its author can act on (nothing is imported)."""
    problems = []
    if not NAME_PATTERN.match(task.name):
        problems.append("a name is lowercase letters, digits and '-' (e.g. 'my-stack')")
    if task.time_limit_s <= 0:
        problems.append(f"time_limit_s must be > 0, got {task.time_limit_s}")
    if not task.env_name:
        problems.append("env_name names the environment class (e.g. 'Stack')")
    if not task.instruction.strip():
        problems.append("instruction is what the worker reads: it cannot be empty")
    unknown = [robot for robot in task.robots if robot not in ROBOSUITE_ARMS]
    if unknown:
        problems.append(f"unknown robot(s) {unknown}; single-arm robots: {list(ROBOSUITE_ARMS)}")
    references = [task.success] + [stage.done_when for stage in task.stages]
    for reference in references:
        if reference is not None and not REFERENCE_PATTERN.match(reference):
            problems.append(f"{reference!r} is not a reference 'package.module:function'")
    problems += _scene_problems(task) + _symmetry_problems(task)
    plan = task.operator_plan
    if plan is not None and ":" in plan and not REFERENCE_PATTERN.match(plan):
        problems.append(f"operator_plan {plan!r} is not a plan's name or 'package.module:plan'")
    if task.env_module is not None and not re.match(r"^[A-Za-z_][\w.]*$", task.env_module):
        problems.append(f"env_module {task.env_module!r} is not a module name")
    return problems


def _symmetry_problems(task: TaskSpec) -> list[str]:
    folds = [f"{name}: {fold}" for name, fold in task.symmetric_objects.items() if fold < 0]
    return [f"symmetric_objects counts turns (>= 0; 0: any turn), got {folds}"] if folds else []


def _scene_problems(task: TaskSpec) -> list[str]:
    if task.scene is not None and task.backend != "mujoco":
        return ["scene is the objects of a plain-MuJoCo task: set backend: mujoco"]
    if task.backend == "mujoco" and task.scene is None and task.env_name != "lift":
        return ["a mujoco task names its objects' MJCF file (scene), or env_name 'lift'"]
    if task.backend == "mujoco" and task.scene is not None and task.success is None:
        return ["a mujoco task with its own scene says when it is done (success)"]
    return []


def resolve(reference: str) -> Any:
    """The object ``"package.module:name"`` names, or a `ConfigError` saying what is missing."""
    module_name, _, attribute = reference.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ImportError as error:
        raise ConfigError(f"cannot import {module_name!r} for {reference!r}: {error}") from None
    try:
        return getattr(module, attribute)
    except AttributeError:
        raise ConfigError(f"module {module_name!r} has no {attribute!r} ({reference!r})") from None


def read_scene(task: TaskSpec) -> str:
    """The text of the task's MJCF file: a path, or "package:file.xml" inside a package."""
    assert task.scene is not None
    package, sep, resource = task.scene.partition(":")
    try:
        if sep and not Path(task.scene).exists():
            return importlib.resources.files(package).joinpath(resource).read_text()
        return Path(task.scene).read_text()
    except (OSError, ImportError, ValueError) as error:
        raise ConfigError(
            f"task {task.name!r}: cannot read its scene {task.scene!r}: {error}"
        ) from None


def import_env_module(task: TaskSpec) -> None:
    """Import the module that defines the task's environment class, so robosuite knows it."""
    if task.env_module is None:
        return
    try:
        importlib.import_module(task.env_module)
    except ImportError as error:
        raise ConfigError(
            f"task {task.name!r}: cannot import env_module {task.env_module!r}: {error}"
        ) from None
