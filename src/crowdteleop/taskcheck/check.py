"""Is the fast path faithful to plain robosuite on this task, and what does it save?

One run measures, on the same robot and controller:

- step time: our control step against robosuite's ``env.step``, the same actions from the
  same reset (medians of a few batches);
- render time: our renderer against MuJoCo's on robosuite's own model and data, which draws
  robosuite's offscreen picture;
- picture fidelity: the two pictures of the same states, as mean absolute difference (0-255)
  and the share of pixels inside strongly differing 3x3 blocks (a missing or misplaced part;
  the edge aliasing we accept by design cannot make one);
- drift: each recorded action stepped in plain robosuite from the state it was recorded in,
  and how far robosuite took the hand from where ours did (robosuite's playback of actions).
  The actions are the task's scripted operator doing the task where it has one (grasps and
  carried objects included), else a random walk of the hand.

The verdict: the fast path is kept where fidelity and drift are within the limits below, which
are the ones the built-in tasks' tests hold (tests/sim/test_render_fidelity.py,
tests/dataset/test_conformance.py).
"""

from __future__ import annotations

import itertools
import statistics
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from crowdteleop.control.config import ControlConfig
from crowdteleop.control.scripted import ScriptedOperator
from crowdteleop.control.scripted.episode import SUCCESS_HOLD_STEPS
from crowdteleop.control.scripted.plans import plan_for
from crowdteleop.control.teleoperator import Teleoperator
from crowdteleop.dataset.robosuite_replay import RobosuiteReplayer
from crowdteleop.errors import ConfigError
from crowdteleop.provenance.env_args import EnvArgs
from crowdteleop.recording.metadata import robosuite_version
from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.sim.rendering import CameraRenderer, picture_difference
from crowdteleop.sim.robosuite_backend import RobosuiteSimulation
from crowdteleop.tasks import get_task

PICTURE_SIZE = (320, 240)
MAD_LIMIT = 1.0  # 0-255, at 320x240 (measured 0.58-0.64 on the built-in tasks)
BLOB_LIMIT = 0.0005  # share of pixels in a strongly differing 3x3 block (measured 0)
DRIFT_MEDIAN_LIMIT_M = 0.001
DRIFT_P95_LIMIT_M = 0.003  # the worst step is reported, not judged: one contact event (a nut
# dropping onto its peg) can part two faithful simulators by centimetres for a step
COLLISION_GEOM_GROUP = 0
TIMED_STEPS = 200  # the first actions, stepped in both simulators for the step times


@dataclass(frozen=True)
class TaskCheck:
    """One task's figures and verdict."""

    task: str
    robot: str
    fast_path: bool
    obstacles: list[str]
    step_ms: float
    robosuite_step_ms: float
    render_ms: float
    robosuite_render_ms: float
    picture_mad: float
    picture_blob: float
    drift_median_m: float
    drift_p95_m: float
    drift_max_m: float
    task_errors: int
    driven_by: str  # "scripted operator" (the task's own plan) or "random walk"

    @property
    def step_ratio(self) -> float:
        return self.robosuite_step_ms / self.step_ms

    @property
    def render_ratio(self) -> float:
        return self.robosuite_render_ms / self.render_ms

    def problems(self) -> list[str]:
        """Why the fast path would not be faithful here; empty when it is."""
        found = []
        if self.picture_mad > MAD_LIMIT:
            found.append(f"picture differs: MAD {self.picture_mad:.2f} > {MAD_LIMIT}")
        if self.picture_blob > BLOB_LIMIT:
            found.append(f"a part is drawn wrong: {self.picture_blob:.2%} of pixels in blobs")
        if self.drift_median_m > DRIFT_MEDIAN_LIMIT_M or self.drift_p95_m > DRIFT_P95_LIMIT_M:
            found.append(
                f"actions drift in plain robosuite: median {self.drift_median_m * 1000:.2f} mm, "
                f"p95 {self.drift_p95_m * 1000:.2f} mm (limits {DRIFT_MEDIAN_LIMIT_M * 1000:g}"
                f" / {DRIFT_P95_LIMIT_M * 1000:g} mm)"
            )
        if self.task_errors:
            found.append(f"the task's own functions raised {self.task_errors} time(s)")
        return found

    def to_json(self) -> dict[str, Any]:
        return asdict(self) | {
            "step_ratio": self.step_ratio,
            "render_ratio": self.render_ratio,
            "problems": self.problems(),
        }


def _random_walk(sim: RobosuiteSimulation, seed: int) -> Iterator[npt.NDArray[np.float64]]:
    """A smooth random walk of the hand (osc-pose deltas); the gripper closes after a while."""
    rng = np.random.default_rng(seed)
    direction = np.zeros(sim.action_spec.size - 1)
    for index in itertools.count():
        direction = 0.8 * direction + 0.2 * rng.uniform(-1, 1, direction.size)
        action = np.append(0.5 * direction, 1.0 if index > 30 else -1.0)
        sim.step(action)
        yield action


def _scripted(sim: RobosuiteSimulation, seed: int) -> Iterator[npt.NDArray[np.float64]]:
    """The task's scripted operator doing the task (grasps, contacts, carried objects), until
    its success has held as long as a recorded episode's does."""
    control = ControlConfig(controller="osc")
    teleop = Teleoperator(sim, control)
    teleop.reset(seed)
    operator = ScriptedOperator(sim, control.mapping, seed=seed)
    held = 0
    while held < SUCCESS_HOLD_STEPS:
        step = teleop.step(operator.command())
        held = held + 1 if step.result.success else 0
        yield step.action


def has_scripted_operator(task: str) -> bool:
    try:
        plan_for(task)
    except ConfigError:
        return False
    return True


def _ms(calls: Callable[[], object], batches: int = 3) -> float:
    """Median of `batches` timings of `calls` (which runs one batch), in ms per batch."""
    timings = []
    for _ in range(batches):
        start = time.perf_counter()
        calls()
        timings.append((time.perf_counter() - start) * 1000)
    return statistics.median(timings)


class _Recording:
    """What our fast path did: states before each action, finger commands, the hands after."""

    def __init__(
        self, sim: RobosuiteSimulation, driver: Iterator[npt.NDArray[np.float64]], steps: int
    ) -> None:
        self.states: list[npt.NDArray[np.float64]] = []
        self.fingers: list[float] = []
        self.actions: list[npt.NDArray[np.float64]] = []
        hands = []
        for _ in range(steps):
            state, finger = sim.get_state(), float(sim.controller_state()[0])
            action = next(driver, None)
            if action is None:  # the episode ended: what follows would not be recorded
                break
            self.states.append(state)
            self.fingers.append(finger)
            self.actions.append(np.asarray(action, dtype=float))
            hands.append(sim.robot_state().end_effector.position)
        self.hands = np.array(hands)


def check_task(task: str, robot: str = "Sawyer", steps: int = 600, seed: int = 0) -> TaskCheck:
    """Measure one task on `robot` with the OSC (the controller datasets replay with)."""
    config = SimConfig(task=task, robot=robot, action_mode="osc-pose")
    if get_task(task).backend != "robosuite":
        raise ValueError(
            f"task {task!r} is not a robosuite task: there is no plain robosuite to check against"
        )
    sim = make_simulation(config)
    assert isinstance(sim, RobosuiteSimulation)
    try:
        return _check(sim, config, steps, seed)
    finally:
        sim.close()


def _check(sim: RobosuiteSimulation, config: SimConfig, steps: int, seed: int) -> TaskCheck:
    sim.reset(seed=seed)
    scripted = has_scripted_operator(config.task)
    driver = _scripted(sim, seed) if scripted else _random_walk(sim, seed)
    recording = _Recording(sim, driver, steps)  # the scripted operator resets with `seed` too
    first, actions = recording.states[0], recording.actions
    posture = sim.nullspace_posture
    replayer = RobosuiteReplayer(EnvArgs.of(config, robosuite_version()), sim.mjcf_xml())
    try:
        theirs = replayer.per_step(recording.states, np.array(actions), posture, recording.fingers)
        drift = np.linalg.norm(theirs.hands - recording.hands, axis=1)
        plain = replayer.env
        positions, rotations = sim.body_placements()
        plain.sim.model._model.body_pos[:] = positions  # robosuite's placements live in
        plain.sim.model._model.body_quat[:] = rotations  # the model: compare like with like
        reference = CameraRenderer(plain.sim.model._model, (COLLISION_GEOM_GROUP,))
        camera = sim.task.default_camera
        mads, blobs = [], []
        for state in recording.states[:: max(1, len(recording.states) // 4)]:
            sim.set_state(state)
            plain.sim.set_state_from_flattened(state)
            plain.sim.forward()
            ours = sim.render(camera, *PICTURE_SIZE)
            figures = picture_difference(
                ours, reference.render(plain.sim.data._data, camera, *PICTURE_SIZE)
            )
            mads.append(figures["mad"])
            blobs.append(figures["blob"])

        timed = actions[:TIMED_STEPS]

        def our_steps() -> None:
            sim.set_state(first)
            for action in timed:
                sim.step(action)

        def plain_steps() -> None:
            plain.sim.set_state_from_flattened(first)
            plain.sim.forward()
            for action in timed:
                plain.step(action)

        def our_frames() -> None:
            for state in recording.states[:10]:
                sim.set_state(state)
                sim.render(camera, *PICTURE_SIZE)

        def plain_frames() -> None:
            for state in recording.states[:10]:
                plain.sim.set_state_from_flattened(state)
                plain.sim.forward()
                reference.render(plain.sim.data._data, camera, *PICTURE_SIZE)

        step_ms = _ms(our_steps) / len(timed)
        robosuite_step_ms = _ms(plain_steps) / len(timed)
        render_ms = _ms(our_frames) / 10
        robosuite_render_ms = _ms(plain_frames) / 10
        reference.close()
    finally:
        replayer.close()
    return TaskCheck(
        task=config.task,
        robot=config.robot,
        fast_path=sim.fast_path,
        obstacles=list(sim.fast_path_obstacles),
        step_ms=step_ms,
        robosuite_step_ms=robosuite_step_ms,
        render_ms=render_ms,
        robosuite_render_ms=robosuite_render_ms,
        picture_mad=max(mads),
        picture_blob=max(blobs),
        drift_median_m=float(np.median(drift)),
        drift_p95_m=float(np.percentile(drift, 95)),
        drift_max_m=float(drift.max()),
        task_errors=sim.judge.errors,
        driven_by="scripted operator" if scripted else "random walk",
    )
