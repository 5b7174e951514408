"""One generation attempt: a new scene, a source segment per subtask moved with its object,
stitched by interpolation, executed with absolute OSC targets on the platform's simulation, and
judged; a failed attempt says why (grasp missed, object dropped, collision, time out).

The targets are absolute, as MimicGen executes them: each step's action is the OSC_POSE delta
that sets the same goal from the current state (`AbsoluteTargets.to_delta`), so what is
recorded is the delta action the platform's recordings hold and plays back exactly.
"""

from __future__ import annotations

import math
import random
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import numpy.typing as npt

from crowdteleop.control.scripted.episode import SUCCESS_HOLD_STEPS
from crowdteleop.dataset.absolute import AbsoluteTargets
from crowdteleop.dataset.generation.poses import (
    Matrix,
    distance,
    from_pose7,
    interpolate,
    inverse,
    moved_with,
    nearest_symmetric,
    rotation_angle,
    to_target,
)
from crowdteleop.dataset.generation.segments import Segment, Subtask
from crowdteleop.recording.episode_file import StepLabels

if TYPE_CHECKING:
    from crowdteleop.sim.interface import Simulation

Strategy = Literal["nearest", "random"]


@dataclass(frozen=True)
class Settings:
    """How segments are chosen and stitched (``dataset generate``'s flags; docs/generation.md)."""

    strategy: Strategy = "nearest"  # the source whose object pose is nearest the new one
    nearest_k: int = 3  # ... chosen at random among the k nearest (MimicGen's nn_k)
    rotation_weight_m: float = 0.05  # metres of distance per radian of object rotation
    per_subtask: bool = False  # choose a source per subtask, not one for the whole attempt
    interpolation_step_m: float = 0.01  # hand speed limit between segments, per step
    interpolation_step_rad: float = 0.1
    min_interpolation_steps: int = 5  # MimicGen's num_interpolation_steps
    settle_steps: int = 10  # steps holding a segment's last target for its subtask to end
    # Gaussian noise (std, in the OSC action's [-1, 1] units) on each executed arm action, as
    # MimicGen's action_noise (0.05 in its task configs): the kept demos then show the way
    # back from small errors. What was executed is what is recorded, so playback stays exact.
    action_noise: float = 0.0
    # Execute on robosuite's own step instead of the fast path (~6x slower): demos whose
    # physics are plain robosuite's (to nanometres), for policies evaluated there (SimConfig's
    # robosuite_step, recorded in each generated episode's sim_config).
    robosuite_step: bool = False


@dataclass
class Attempt:
    """What one attempt did: its steps (states before actions), labels and outcome."""

    index: int
    seed: int
    success: bool = False
    reason: str = ""
    failed_subtask: str = ""
    states: list[npt.NDArray[np.float64]] = field(default_factory=list)
    actions: list[npt.NDArray[np.float64]] = field(default_factory=list)
    rewards: list[float] = field(default_factory=list)
    successes: list[bool] = field(default_factory=list)
    contacts: list[list[dict[str, Any]]] = field(default_factory=list)
    labels: list[StepLabels] = field(default_factory=list)
    durations_s: list[float] = field(default_factory=list)
    chosen: list[dict[str, Any]] = field(default_factory=list)  # provenance per subtask
    model_xml: str = ""
    sim_config: dict[str, Any] = field(default_factory=dict)  # what it was simulated with
    worker: str = ""  # which process (and Ray node) ran it
    controller_state_at_start: list[float] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def steps(self) -> int:
        return len(self.actions)


class _Executor:
    """Steps absolute world-frame targets and records every step."""

    def __init__(
        self, sim: Simulation, absolute: AbsoluteTargets, attempt: Attempt, noise: float = 0.0
    ) -> None:
        self.sim = sim
        self._absolute = absolute
        self._noise = noise
        self._rng = np.random.default_rng(attempt.seed)  # the same noise when resumed
        self._to_base = inverse(absolute.base_frame(sim.get_state()))
        self.attempt = attempt
        self.held = 0  # steps success has held
        self.label = StepLabels.read(sim)

    def step(self, target: Matrix, gripper: float) -> None:
        sim, attempt = self.sim, self.attempt
        state = sim.get_state()
        goal = np.concatenate([to_target(self._to_base @ target), [gripper]])
        action = self._absolute.to_delta(state, goal)
        if self._noise:
            arm = action[:-1] + self._rng.normal(0.0, self._noise, len(action) - 1)
            action = np.concatenate([np.clip(arm, -1.0, 1.0), action[-1:]])
        started = time.perf_counter()
        result = sim.step(action)
        attempt.durations_s.append(time.perf_counter() - started)
        attempt.states.append(state)
        attempt.actions.append(action)
        attempt.labels.append(self.label)
        attempt.rewards.append(float(result.reward))
        attempt.successes.append(bool(result.success))
        attempt.contacts.append([vars(c) for c in result.contacts])
        self.held = self.held + 1 if result.success else 0
        self.label = StepLabels.read(sim)

    def touched(self) -> set[str]:
        return {c["object"] for c in self.attempt.contacts[-1]} if self.attempt.contacts else set()


def _stage_index(label: StepLabels, subtasks: list[Subtask]) -> int:
    """Which subtask the state is in (len: done; -1: a label no subtask has)."""
    if label.stage == "done":
        return len(subtasks)
    for k, subtask in enumerate(subtasks):
        if (label.stage, label.relative_to) == (subtask.stage, subtask.relative_to):
            return k
    return -1


def choose_source(scene: Scene, k: int, new_object: Matrix, rng: random.Random) -> list[Segment]:
    """A source demo for subtask k: random, or at random among the k nearest by object pose
    (its symmetric turns counted as the same pose)."""
    sources, settings = scene.sources, scene.settings
    if settings.strategy == "random":
        return rng.choice(sources)

    def far(i: int) -> float:
        old = sources[i][k].object_at_start
        return distance(old, scene.symmetric(k, new_object, old), settings.rotation_weight_m)

    ranked = sorted(range(len(sources)), key=far)
    return sources[rng.choice(ranked[: max(1, settings.nearest_k)])]


def _interpolation_steps(start: Matrix, end: Matrix, settings: Settings) -> int:
    moves = float(np.linalg.norm(end[:3, 3] - start[:3, 3])) / settings.interpolation_step_m
    turns = rotation_angle(start, end) / settings.interpolation_step_rad
    return max(settings.min_interpolation_steps, math.ceil(max(moves, turns)))


@dataclass(frozen=True)
class Scene:
    """What every attempt shares: the simulation, its targets' maths, the sources."""

    sim: Simulation
    absolute: AbsoluteTargets
    subtasks: list[Subtask]
    sources: list[list[Segment]]
    max_steps: int
    settings: Settings
    symmetry: dict[str, int] = field(default_factory=dict)  # the task's symmetric_objects

    def symmetric(self, k: int, frame: Matrix, reference: Matrix) -> Matrix:
        """Subtask k's object frame turned by its symmetry to be nearest ``reference``."""
        fold = self.symmetry.get(self.subtasks[k].relative_to, 1)
        return nearest_symmetric(frame, reference, fold)


def run_attempt(scene: Scene, index: int, seed: int) -> Attempt:
    """Generate in scene ``seed`` (the task's own initializer); never raises on a failed
    attempt, which says why in ``reason``."""
    started = time.perf_counter()
    sim, settings = scene.sim, scene.settings
    sim.reset(seed)
    attempt = Attempt(index, seed)
    attempt.model_xml = sim.mjcf_xml()
    attempt.sim_config = sim.config.model_dump(mode="json")
    attempt.controller_state_at_start = [float(v) for v in sim.controller_state()]
    run = _Executor(sim, scene.absolute, attempt, settings.action_noise)
    rng = random.Random(seed)
    current = from_pose7(run.label.hand_pose)
    gripper = -1.0
    source: list[Segment] | None = None
    for k, subtask in enumerate(scene.subtasks):
        new_object = from_pose7(run.label.object_poses[subtask.relative_to])
        if source is None or settings.per_subtask:
            source = choose_source(scene, k, new_object, rng)
        segment = source[k]
        new_object = scene.symmetric(k, new_object, segment.object_at_start)
        path = moved_with(segment.targets, segment.object_at_start, new_object)
        attempt.chosen.append(
            {
                "subtask": str(subtask),
                "demo": segment.demo,
                "start": segment.start,
                "end": segment.end,
            }
        )
        collision = _interpolate(run, current, path[0], gripper, settings)
        for target, grip in zip(path, segment.gripper, strict=True):
            if attempt.steps >= scene.max_steps:
                return _failed(attempt, subtask, "time out", started)
            run.step(target, float(grip))
        current, gripper = path[-1], float(segment.gripper[-1])
        last = k + 1 == len(scene.subtasks)
        reason = _settle(run, current, gripper, k, scene, last)
        if reason:
            if collision:
                reason = (
                    f"collision during the interpolation into {subtask.stage} ({collision}); "
                    + reason
                )
            return _failed(attempt, subtask, reason, started)
    attempt.success = True
    attempt.seconds = time.perf_counter() - started
    return attempt


def _interpolate(
    run: _Executor, start: Matrix, end: Matrix, gripper: float, settings: Settings
) -> str:
    """Move to a segment's first target; the first object newly touched on the way, if any."""
    before = run.touched()
    collision = ""
    for target in interpolate(start, end, _interpolation_steps(start, end, settings)):
        run.step(target, gripper)
        new = run.touched() - before
        if new and not collision:
            collision = f"the hand touched {sorted(new)[0]}"
    return collision


def _settle(
    run: _Executor, target: Matrix, gripper: float, k: int, scene: Scene, last: bool
) -> str:
    """Hold the segment's last target until its subtask has ended (the last: success held);
    why not, or "" when it did."""
    subtasks = scene.subtasks
    extra = scene.settings.settle_steps + (SUCCESS_HOLD_STEPS if last else 0)
    for _ in range(extra + 1):
        if last and run.held >= SUCCESS_HOLD_STEPS:
            return ""
        if not last and _stage_index(run.label, subtasks) > k:
            return ""
        if run.attempt.steps >= scene.max_steps:
            break
        run.step(target, gripper)
    now = _stage_index(run.label, subtasks)
    if 0 <= now < k:
        return f"dropped the {subtasks[now].relative_to}"
    if last:
        return "time out: the task's success did not hold"
    if now == k and subtasks[k].stage == "reach":
        return f"grasp missed ({subtasks[k].relative_to})"
    return f"{subtasks[k].stage} not finished"


def _failed(attempt: Attempt, subtask: Subtask, reason: str, started: float) -> Attempt:
    attempt.reason = reason
    attempt.failed_subtask = str(subtask)
    attempt.seconds = time.perf_counter() - started
    return attempt
