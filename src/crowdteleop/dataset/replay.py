"""Re-simulating demonstrations: state replay (exact, filmed) and action replay (drift).

The recording's ``sim_config`` (model_seed included) rebuilds the very model it was recorded
on; that is checked against the stored MJCF before anything is compared. State replay sets
each recorded state and must read it back bit for bit; stepping each recorded action from the
state before it must land on the next recorded state. Action replay steps all actions open
loop from the first state and reports how far the states drift: the number the "demos do not
replay from their actions" complaint is about, measured for every demo at build time.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
from pydantic import ValidationError

from crowdteleop.dataset.files import DatasetError, open_dataset
from crowdteleop.provenance.env_args import EnvArgs
from crowdteleop.recording.episode_file import CorruptEpisodeError, Episode, read_episode
from crowdteleop.recording.metadata import EpisodeMetadata, robosuite_version
from crowdteleop.sim.mjcf import same_model

if TYPE_CHECKING:  # the interface's types load MuJoCo; reading a dataset should not
    from crowdteleop.sim.interface import Simulation


@dataclass(frozen=True)
class Demo:
    """What replaying one demonstration needs."""

    name: str
    states: npt.NDArray[np.float64]
    actions: npt.NDArray[np.float64]
    model_xml: str
    metadata: dict[str, Any]
    env_args: EnvArgs | None = None  # robomimic's, as the file recorded them

    @functools.cached_property
    def info(self) -> EpisodeMetadata:
        """The metadata, typed (defaults where an older recording lacks a field)."""
        return EpisodeMetadata.model_validate(self.metadata)


@dataclass(frozen=True)
class DriftResult:
    steps: int
    max_state_error: float  # max |replayed - recorded| over every state entry and step
    final_state_error: float
    max_qpos_error: float


@dataclass(frozen=True)
class RobosuiteDrift:
    """Where plain robosuite (its own Python OSC) takes the hand, vs where ours went."""

    steps: int
    per_step_median_m: float  # each action stepped from its recorded state
    per_step_max_m: float
    open_loop_max_m: float  # all actions from the first state: the playback complaint
    open_loop_final_m: float
    open_loop_at_m: dict[int, float]  # steps -> hand error after that many open-loop steps


@dataclass(frozen=True)
class ReplayResult:
    frames: int
    state_exact: bool  # every state read back bit for bit
    step_exact: bool  # each action from its recorded state reproduced the next state exactly
    max_step_error: float
    drift: DriftResult
    output: Path | None


def load_demo(path: Path, demo: str | None = None) -> Demo:
    """A demo from a built dataset (``demo`` e.g. "demo_1", default the first) or an episode."""
    path = Path(path)
    try:
        episode = read_episode(path)
    except CorruptEpisodeError:
        episode = None
    if episode is not None:
        return demo_of_episode(episode)
    with open_dataset(path) as file:
        names = sorted(file["data"], key=lambda n: int(n.split("_")[-1]))
        name = demo or (names[0] if names else "")
        if name not in file["data"]:
            raise DatasetError(f"{path} has no {demo!r}; it holds {', '.join(names[:5])}...")
        group = file["data"][name]
        return Demo(
            name=name,
            states=group["states"][()],
            actions=group["actions"][()],
            model_xml=str(group.attrs["model_file"]),
            metadata=json.loads(group.attrs["metadata"]),
            env_args=_env_args(file["data"].attrs["env_args"], f"{path}'s data"),
        )


def demo_of_episode(episode: Episode) -> Demo:
    if episode.model_xml is None:
        raise DatasetError(f"episode {episode.episode_id} has no model_file")
    return Demo(
        "demo_0",
        episode.states,
        episode.actions,
        episode.model_xml,
        episode.metadata,
        None if episode.env_args is None else _env_args(episode.env_args, episode.episode_id),
    )


def _env_args(recorded: str | Mapping[str, Any] | EnvArgs, where: str) -> EnvArgs:
    """A file's ``env_args`` typed: from its JSON, or the dict robomimic (or an episode file)
    reads from it."""
    try:
        if isinstance(recorded, EnvArgs):
            return recorded
        if isinstance(recorded, Mapping):
            return EnvArgs.model_validate(recorded)
        return EnvArgs.model_validate_json(recorded)
    except ValidationError as error:
        raise DatasetError(f"{where}: env_args are not robomimic's: {error}") from error


def recorded_env_args(demo: Demo) -> EnvArgs:
    """robomimic's ``env_args`` for a demo, derived from its recorded ``sim_config``."""
    from crowdteleop.sim import SimConfig

    return EnvArgs.of(SimConfig(**recorded_sim_config(demo)), robosuite_version())


def recorded_sim_config(demo: Demo) -> dict[str, Any]:
    """The demo's ``sim_config`` as recorded, with the values keys added since had then
    (`SimConfig.from_recorded`): e.g. no finger ramp before ``gripper_ramp`` existed."""
    from crowdteleop.sim import SimConfig

    if not demo.info.sim_config:
        raise DatasetError(f"{demo.name} has no sim_config: it cannot be re-simulated")
    return SimConfig.from_recorded(demo.info.sim_config).model_dump(mode="json")


class ReplayChecker:
    """Builds (and reuses) one simulation per recorded ``sim_config``."""

    def __init__(self) -> None:
        self._sims: dict[str, Simulation] = {}

    def __enter__(self) -> ReplayChecker:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        for sim in self._sims.values():
            sim.close()
        self._sims.clear()

    def simulation(self, demo: Demo, robosuite_step: bool = False) -> Simulation:
        """The recording's simulation, checked to hold the recorded model; ``robosuite_step``
        steps it with robosuite's own step whatever it was recorded with."""
        from crowdteleop.sim import SimConfig, make_simulation

        raw = recorded_sim_config(demo) | ({"robosuite_step": True} if robosuite_step else {})
        key = json.dumps(raw, sort_keys=True)
        if key not in self._sims:
            self._sims[key] = make_simulation(SimConfig(**raw))
        sim = self._sims[key]
        if not same_model(demo.model_xml, sim.mjcf_xml()):
            raise DatasetError(
                f"{demo.name}: its sim_config no longer builds the recorded model (another "
                "crowdteleop or robosuite version?); replay it with the versions it names"
            )
        return sim

    def start(self, demo: Demo) -> Simulation:
        """The simulation at the demo's first state, reset as its episode was.

        ``reset_seed`` (if recorded) matters for ``osc-pose`` demos: robosuite's OSC pulls its
        null space toward the episode's first joint posture, set at reset and not part of the
        state, so without it one-step replay is not exact (the joint-velocity servo has no
        such memory)."""
        sim = self.simulation(demo)
        seed = demo.info.reset_seed
        if seed is not None:
            sim.reset(seed=seed)
        sim.set_state(demo.states[0])
        start = demo.info.controller_state_at_start
        if start is not None:
            sim.set_controller_state(np.array(start, dtype=float))
        return sim

    def action_drift(self, source: Demo | Episode) -> DriftResult:
        demo = source if isinstance(source, Demo) else demo_of_episode(source)
        sim = self.start(demo)
        errors, qpos_errors = [], []
        n_qpos = (demo.states.shape[1] - 1) // 2 + 1  # [time, qpos, qvel]: qpos may be longer
        for action, recorded in zip(demo.actions[:-1], demo.states[1:], strict=True):
            sim.step(action)
            diff = np.abs(sim.get_state() - recorded)
            errors.append(float(diff.max()))
            qpos_errors.append(float(diff[1:n_qpos].max()))
        return DriftResult(
            steps=len(demo.actions),
            max_state_error=max(errors, default=0.0),
            final_state_error=errors[-1] if errors else 0.0,
            max_qpos_error=max(qpos_errors, default=0.0),
        )

    def robosuite_drift(
        self, demo: Demo, env_args: EnvArgs | Mapping[str, Any] | None = None
    ) -> RobosuiteDrift:
        """Action replay in plain robosuite rebuilt from ``env_args`` (default: the demo's
        file's), per step from each recorded state and open loop from the first, against our
        hand. Files recorded before ``env_args`` named the controller get it from their
        ``sim_config``."""
        from crowdteleop.dataset.robosuite_replay import RobosuiteReplayer

        recorded = demo.env_args if env_args is None else _env_args(env_args, demo.name)
        if recorded is None or recorded.controller is None:
            recorded = recorded_env_args(demo)

        sim = self.start(demo)
        initial_joints = sim.robot_state().joint_positions.copy()
        controller = sim.controller_state()
        ours, commands = [], []
        for state, action in zip(demo.states, demo.actions, strict=True):
            sim.set_state(state)
            sim.set_controller_state(controller)
            commands.append(float(controller[0]) if controller.size else 0.0)
            sim.step(action)
            controller = sim.controller_state()
            ours.append(sim.robot_state().end_effector.position.copy())
        replayer = RobosuiteReplayer(recorded, demo.model_xml)
        try:
            per_step = replayer.per_step(list(demo.states), demo.actions, initial_joints, commands)
            open_loop = replayer.open_loop(
                demo.states[0], demo.actions, initial_joints, commands[0]
            )
        finally:
            replayer.close()
        step_error = np.linalg.norm(np.array(ours) - per_step.hands, axis=1)
        open_error = np.linalg.norm(np.array(ours) - open_loop.hands, axis=1)
        return RobosuiteDrift(
            steps=len(demo.actions),
            per_step_median_m=float(np.median(step_error)),
            per_step_max_m=float(step_error.max()),
            open_loop_max_m=float(open_error.max()),
            open_loop_final_m=float(open_error[-1]),
            open_loop_at_m={n: float(open_error[n - 1]) for n in (5, 20, 40) if n <= len(ours)},
        )

    def replay(
        self,
        demo: Demo,
        camera: str | None = None,
        width: int = 320,
        height: int = 240,
        output: Path | None = None,
        progress: Callable[[int, int], None] | None = None,
    ) -> ReplayResult:
        """Set every recorded state (filmed to ``output`` if given), then measure drift."""
        from crowdteleop.dataset.video import Mp4Writer

        sim = self.start(demo)
        controller = sim.controller_state()
        camera = camera or demo.info.camera
        state_exact = step_exact = True
        max_step_error = 0.0
        frames = 0
        writer = Mp4Writer(output, round(1.0 / sim.control_dt)) if output is not None else None
        try:
            if writer is not None:
                writer.__enter__()
            for i, state in enumerate(demo.states):
                sim.set_state(state)
                state_exact &= bool(np.array_equal(sim.get_state(), state))
                if writer is not None:
                    writer.write(sim.render(camera, width, height))
                    frames += 1
                if i + 1 < len(demo.states):
                    sim.set_controller_state(controller)
                    sim.step(demo.actions[i])
                    controller = sim.controller_state()
                    error = float(np.abs(sim.get_state() - demo.states[i + 1]).max())
                    max_step_error = max(max_step_error, error)
                    step_exact &= error == 0.0
                if progress is not None:
                    progress(i + 1, len(demo.states))
        finally:
            if writer is not None:
                writer.__exit__(None, None, None)
        return ReplayResult(
            frames, state_exact, step_exact, max_step_error, self.action_drift(demo), output
        )
