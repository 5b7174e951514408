"""A trained policy run closed loop in the two simulations a dataset can name: ours, rebuilt
from the demos' recorded ``sim_config``, and plain robosuite, rebuilt from ``env_args`` alone
(what a robomimic user would do with our file). The gap between the two is the measure of
"policies transfer".

Both reseed robosuite's ``env.rng`` per episode (robosuite draws object placement and joint
noise from it), so episode ``k`` starts from the same scene in both; success is
``env._check_success()`` at any step, and an episode ends at its first success.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
import numpy.typing as npt

from crowdteleop.learn.bc import Checkpoint, Policy

SimName = Literal["ours", "robosuite"]
Obs = dict[str, npt.NDArray[np.float64]]
HORIZONS = {"Lift": 400, "PickPlaceCan": 500}  # robomimic's rollout horizons
DEFAULT_HORIZON = 500
PLAIN_DEFAULTS = {
    "has_renderer": False,
    "has_offscreen_renderer": False,
    "use_camera_obs": False,
    "ignore_done": True,
}
VIDEO_CAMERA = "frontview"
TRACE_KEYS = ("robot0_eef_pos", "robot0_gripper_qpos", "object")


class RolloutEnv(Protocol):
    """The little the evaluator needs of an environment."""

    def reset(self, seed: int) -> Obs: ...

    def step(self, action: npt.NDArray[np.float64]) -> tuple[Obs, bool]: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class EpisodeOutcome:
    seed: int
    success: bool
    steps: int  # to the first success, else the horizon
    trace: dict[str, list[list[float]]] | None = None  # TRACE_KEYS and actions, per step


@dataclass(frozen=True)
class EvalReport:
    sim: SimName
    horizon: int
    episodes: list[EpisodeOutcome] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def success_rate(self) -> float:
        return sum(e.success for e in self.episodes) / max(1, len(self.episodes))

    @property
    def mean_steps_to_success(self) -> float | None:
        steps = [e.steps for e in self.episodes if e.success]
        return float(np.mean(steps)) if steps else None

    def summary(self) -> dict[str, Any]:
        return {
            "sim": self.sim,
            "episodes": len(self.episodes),
            "successes": sum(e.success for e in self.episodes),
            "success_rate": self.success_rate,
            "mean_steps_to_success": self.mean_steps_to_success,
            "horizon": self.horizon,
            "seconds": self.seconds,
            "per_episode": [
                {"seed": e.seed, "success": e.success, "steps": e.steps} for e in self.episodes
            ],
        }


def default_horizon(checkpoint: Checkpoint) -> int:
    return HORIZONS.get(
        str(checkpoint.dataset.get("env_args", {}).get("env_name")), DEFAULT_HORIZON
    )


def evaluate(
    checkpoint: Checkpoint,
    sim: SimName,
    episodes: int,
    horizon: int | None = None,
    seed: int = 0,
    rnn_horizon: int | None = None,
    trace: bool = False,
    video: Path | None = None,
    video_episodes: int = 2,
) -> EvalReport:
    """``episodes`` rollouts with seeds ``seed, seed + 1, ...`` in one simulation; in ours,
    ``video`` keeps the first ``video_episodes`` as an MP4."""
    horizon = default_horizon(checkpoint) if horizon is None else horizon
    policy = Policy(checkpoint, rnn_horizon)
    started = time.perf_counter()
    outcomes = []
    clips: list[npt.NDArray[np.uint8]] = []
    with open_env(checkpoint, sim) as env:
        for k in range(episodes):
            frames: list[npt.NDArray[np.uint8]] | None = None
            if video is not None and isinstance(env, OurEnv) and k < video_episodes:
                frames = []
            outcomes.append(run_episode(env, policy, seed + k, horizon, trace, frames))
            clips.extend(frames or [])
    if video is not None and clips:
        from crowdteleop.dataset.video import Mp4Writer

        with Mp4Writer(video, fps=20) as writer:
            for frame in clips:
                writer.write(frame)
    return EvalReport(sim, horizon, outcomes, time.perf_counter() - started)


def run_episode(
    env: RolloutEnv,
    policy: Policy,
    seed: int,
    horizon: int,
    trace: bool = False,
    frames: list[npt.NDArray[np.uint8]] | None = None,
) -> EpisodeOutcome:
    obs = env.reset(seed)
    policy.reset(seed)
    record: dict[str, list[list[float]]] | None = (
        {key: [] for key in (*TRACE_KEYS, "action")} if trace else None
    )
    for step in range(1, horizon + 1):
        action = policy.act(obs)
        if record is not None:
            for key in TRACE_KEYS:
                record[key].append(obs[key].tolist())
            record["action"].append(action.tolist())
        obs, success = env.step(action)
        if frames is not None and isinstance(env, OurEnv):
            frames.append(env.sim.render(VIDEO_CAMERA, 256, 256))
        if success:
            return EpisodeOutcome(seed, True, step, record)
    return EpisodeOutcome(seed, False, horizon, record)


@contextmanager
def open_env(checkpoint: Checkpoint, sim: SimName) -> Iterator[RolloutEnv]:
    env: RolloutEnv = OurEnv(checkpoint) if sim == "ours" else PlainRobosuiteEnv(checkpoint)
    try:
        yield env
    finally:
        env.close()


class OurEnv:
    """The platform's simulation from the demos' ``sim_config`` (fast physics path). A policy
    of absolute targets drives its delta OSC through `AbsoluteTargets.to_delta`."""

    def __init__(self, checkpoint: Checkpoint) -> None:
        from crowdteleop.dataset.absolute import AbsoluteTargets
        from crowdteleop.learn.data import LearnDataError
        from crowdteleop.sim import SimConfig, make_simulation

        sim_config = checkpoint.dataset.get("sim_config")
        if not sim_config:
            raise LearnDataError("the checkpoint's dataset recorded no sim_config")
        self.sim = make_simulation(SimConfig.from_recorded(sim_config))
        self._targets: AbsoluteTargets | None = None
        if checkpoint.config.actions == "actions_abs":
            kwargs = checkpoint.dataset.get("env_args", {}).get("env_kwargs", {})
            arm = kwargs.get("controller_configs", {}).get("body_parts", {}).get("right", {})
            if arm.get("type") != "OSC_POSE":
                self.sim.close()
                raise LearnDataError(
                    "an actions_abs policy rolls out in our simulation for osc demos only "
                    f"(these were recorded with {arm.get('type') or 'an unknown controller'}); "
                    "evaluate it with --sim robosuite"
                )
            self._targets = AbsoluteTargets(self.sim.kinematics(), arm)

    def reset(self, seed: int) -> Obs:
        self.sim.reset(seed)
        return self.sim.observations()

    def step(self, action: npt.NDArray[np.float64]) -> tuple[Obs, bool]:
        if self._targets is not None:
            action = self._targets.to_delta(self.sim.get_state(), action)
        result = self.sim.step(np.clip(action, self.sim.action_spec.low, self.sim.action_spec.high))
        return self.sim.observations(), bool(result.success)

    def close(self) -> None:
        self.sim.close()


def plain_env_kwargs(env_args: dict[str, Any]) -> dict[str, Any]:
    """``env_args["env_kwargs"]`` plus headless defaults for the keys it leaves out."""
    return {**PLAIN_DEFAULTS, **dict(env_args.get("env_kwargs") or {})}


def make_plain_robosuite(env_args: dict[str, Any], **overrides: Any) -> Any:
    """``robosuite.make(env_name, **env_kwargs)`` from ``env_args`` alone (plus ``overrides``),
    as a robomimic user would rebuild the scene."""
    import os

    os.environ.setdefault("PYNPUT_BACKEND", "dummy")  # robosuite.devices wants a display
    import robosuite

    from crowdteleop.learn.data import LearnDataError

    if "env_name" not in env_args:
        raise LearnDataError("the dataset has no env_args to rebuild plain robosuite from")
    return robosuite.make(env_args["env_name"], **{**plain_env_kwargs(env_args), **overrides})


def reseed_plain(env: Any, seed: int) -> None:
    """Episode ``seed``'s scene: ``env.rng`` reseeded in place (robosuite's placement
    samplers hold a reference to it)."""
    env.rng.bit_generator.state = np.random.default_rng(seed).bit_generator.state


class PlainRobosuiteEnv:
    """``robosuite.make(env_name, **env_kwargs)`` and nothing of ours but the key renaming."""

    def __init__(self, checkpoint: Checkpoint) -> None:
        from crowdteleop.learn.data import LearnDataError

        overrides = {}
        if checkpoint.config.actions == "actions_abs":
            configs = checkpoint.dataset.get("abs_controller_configs")
            if not configs:
                raise LearnDataError("the dataset named no actions_abs_controller_configs")
            overrides["controller_configs"] = configs  # robosuite's OSC in absolute input mode
        self.env = make_plain_robosuite(checkpoint.dataset.get("env_args") or {}, **overrides)
        low, high = self.env.action_spec
        self._low, self._high = np.asarray(low), np.asarray(high)
        if checkpoint.config.actions == "actions_abs":
            # robosuite reports input_min / input_max (+-1) as the action spec, but its
            # absolute OSC reads the pose as it is: clipping would cut rotations past 1 rad
            self._low, self._high = (
                np.full_like(self._low, -np.inf),
                np.full_like(self._high, np.inf),
            )

    def reset(self, seed: int) -> Obs:
        from crowdteleop.sim.types import low_dim_keys

        reseed_plain(self.env, seed)
        return low_dim_keys(self.env.reset())

    def step(self, action: npt.NDArray[np.float64]) -> tuple[Obs, bool]:
        from crowdteleop.sim.types import low_dim_keys

        obs, _, _, _ = self.env.step(np.clip(action, self._low, self._high))
        return low_dim_keys(obs), bool(self.env._check_success())

    def close(self) -> None:
        self.env.close()
