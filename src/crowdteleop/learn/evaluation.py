"""A trained policy run closed loop: one routine (`evaluate`: a policy, an environment of
`learn.envs`, seeds -> per-episode results and a summary) for BC-RNN checkpoints, PPO runs,
PPO's learning curve and the transfer benchmark.

- BC (`evaluate_checkpoint`): robomimic's rollout, ending at the first solved step, else after
  the horizon (400 for Lift, 500 otherwise); success is solved at any step.
- PPO (`evaluate_run`): the paper's, from normal resets for ``horizon`` steps (1000) with no
  early stop; the return counts the solved steps, so a policy that solves the task at once and
  holds it scores the horizon; success is solved at any step.

Either runs in our simulation or in plain robosuite rebuilt from the dataset's ``env_args``
alone: the gap between the two is the measure of "policies transfer".
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
import numpy.typing as npt

from crowdteleop.learn.data import LearnDataError
from crowdteleop.learn.envs import (
    Action,
    EnvSettings,
    Image,
    Observation,
    SimName,
    TaskEnv,
    make_env,
    robosuite_scene,
)

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm
    from stable_baselines3.common.vec_env import VecNormalize

    from crowdteleop.learn.bc import Checkpoint

HORIZONS = {"Lift": 400, "PickPlaceCan": 500}  # robomimic's rollout horizons
DEFAULT_HORIZON = 500
EVAL_HORIZON = 1000  # the paper's "maximum possible return ... is 1000"
TRACE_KEYS = ("robot0_eef_pos", "robot0_gripper_qpos", "object")
Trace = dict[str, list[list[float]]]  # TRACE_KEYS and "action", one row per step


class Agent(Protocol):
    """What the evaluation needs of a policy."""

    def reset(self, seed: int) -> None:
        """Before each episode (a stochastic policy reseeds its sampling)."""

    def act(self, obs: Observation) -> Action: ...


@dataclass(frozen=True)
class Episode:
    seed: int
    success: bool  # solved at any step
    steps: int  # steps run: to the first success when episodes stop there, else the horizon
    first_success_step: int | None
    episode_return: float  # solved steps (the sparse reward's sum)
    trace: Trace | None = None
    error: str | None = None  # the simulator aborted the episode here (MuJoCo's fatal error)


@dataclass(frozen=True)
class EvalReport:
    sim: SimName
    horizon: int
    stops_at_success: bool  # BC's rollouts; PPO's run the horizon and count the return
    episodes: list[Episode] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def successes(self) -> int:
        return sum(e.success for e in self.episodes)

    @property
    def success_rate(self) -> float:
        return self.successes / max(1, len(self.episodes))

    @property
    def errors(self) -> list[str]:
        """Why each episode the simulator aborted ended (one line per episode)."""
        return [f"seed {e.seed}, step {e.steps}: {e.error}" for e in self.episodes if e.error]

    @property
    def mean_steps_to_success(self) -> float | None:
        steps = [e.first_success_step for e in self.episodes if e.first_success_step is not None]
        return float(np.mean(steps)) if steps else None

    @property
    def mean_return(self) -> float:
        return float(np.mean([e.episode_return for e in self.episodes]))

    @property
    def std_return(self) -> float:
        return float(np.std([e.episode_return for e in self.episodes]))

    def summary(self) -> dict[str, object]:
        """``eval.json``'s entry for this simulation (the return only where it counts every
        solved step; `learn table` reads its absence as "successes only")."""
        summary: dict[str, object] = {
            "sim": self.sim,
            "episodes": len(self.episodes),
            "successes": self.successes,
            "success_rate": self.success_rate,
            "mean_steps_to_success": self.mean_steps_to_success,
            "simulator_errors": len(self.errors),
        }
        if not self.stops_at_success:
            summary |= {"mean_return": self.mean_return, "std_return": self.std_return}
        summary |= {"horizon": self.horizon, "seconds": round(self.seconds, 1)}
        summary["per_episode"] = [self._episode_summary(e) for e in self.episodes]
        return summary

    def _episode_summary(self, episode: Episode) -> dict[str, object]:
        row: dict[str, object] = {
            "seed": episode.seed,
            "success": episode.success,
            "steps": episode.steps,
            "first_success_step": episode.first_success_step,
        }
        if not self.stops_at_success:
            row["episode_return"] = episode.episode_return
        if episode.error is not None:
            row["error"] = episode.error
        return row


def evaluate(
    agent: Agent,
    env: TaskEnv,
    seeds: Iterable[int],
    trace: bool = False,
    video: Path | None = None,
    video_episodes: int = 2,
) -> EvalReport:
    """One episode per seed, each from a normal reset of scene ``seed`` and run until the
    environment ends it (its horizon, or its first solved step with ``terminate_on_success``).
    ``trace`` keeps `TRACE_KEYS` and the action of every step; ``video`` films the first
    ``video_episodes`` (an environment made with ``render_mode="rgb_array"``) as an MP4."""
    started = time.perf_counter()
    episodes, clips = [], []
    for k, seed in enumerate(seeds):
        frames: list[Image] | None = [] if video is not None and k < video_episodes else None
        episodes.append(run_episode(env, agent, seed, trace, frames))
        clips.extend(frames or [])
    if video is not None and clips:
        from crowdteleop.dataset.video import Mp4Writer

        with Mp4Writer(video, fps=20) as writer:
            for frame in clips:
                writer.write(frame)
    settings = env.settings
    return EvalReport(
        env.name,
        settings.horizon,
        settings.terminate_on_success,
        episodes,
        time.perf_counter() - started,
    )


def run_episode(
    env: TaskEnv,
    agent: Agent,
    seed: int,
    trace: bool = False,
    frames: list[Image] | None = None,
) -> Episode:
    """One rollout. A policy can drive MuJoCo into a state it aborts on (e.g. more contacts
    for a geom pair than its collision function allows, seen in plain robosuite): the episode
    then ends there, with what it reached and the error, and the next one runs."""
    import mujoco

    obs, _ = env.reset(seed=seed)
    agent.reset(seed)
    record: Trace | None = {key: [] for key in (*TRACE_KEYS, "action")} if trace else None
    total, first, steps = 0.0, None, 0
    while True:
        action = agent.act(obs)
        if record is not None:
            named = env.named_observations()
            for key in TRACE_KEYS:
                record[key].append(named[key].tolist())
            record["action"].append(np.asarray(action).tolist())
        try:
            obs, reward, terminated, truncated, info = env.step(action)
        except mujoco.FatalError as error:
            return Episode(seed, first is not None, steps, first, total, record, str(error))
        steps += 1
        total += float(reward)
        if info["success"] and first is None:
            first = steps
        if frames is not None:
            frame = env.render()
            if frame is not None:
                frames.append(frame)
        if terminated or truncated:
            return Episode(seed, first is not None, steps, first, total, record)


# --- BC-RNN checkpoints (`learn bc`) ---


def default_horizon(checkpoint: Checkpoint) -> int:
    env_args = _mapping(checkpoint.dataset, "env_args")
    if not env_args:
        return DEFAULT_HORIZON
    return HORIZONS.get(robosuite_scene(env_args).env_name, DEFAULT_HORIZON)


def _mapping(values: Mapping[str, object], key: str) -> Mapping[str, object] | None:
    value = values.get(key)
    return value if isinstance(value, Mapping) and value else None


def checkpoint_env(
    checkpoint: Checkpoint,
    sim: SimName,
    horizon: int | None = None,
    render_mode: str | None = None,
) -> TaskEnv:
    """The environment a BC checkpoint is rolled out in: its dataset's scene, its observation
    keys and actions, episodes ending at the first solved step."""
    from crowdteleop.sim import SimConfig

    dataset = checkpoint.dataset
    recorded = _mapping(dataset, "sim_config")
    settings = EnvSettings(
        # as it rebuilds now: keys added since take the values they had then
        sim_config=SimConfig.from_recorded(recorded).model_dump(mode="json") if recorded else {},
        horizon=default_horizon(checkpoint) if horizon is None else horizon,
        obs_keys=checkpoint.obs_keys,
        demo_reset_p=0.0,
        terminate_on_success=True,
        actions=checkpoint.config.actions,
    )
    env_args = _mapping(dataset, "env_args")
    abs_configs = _mapping(dataset, "abs_controller_configs")
    scene = robosuite_scene(env_args, abs_configs) if env_args else None
    return make_env(settings, sim=sim, scene=scene, render_mode=render_mode)


@contextmanager
def open_env(checkpoint: Checkpoint, sim: SimName, horizon: int | None = None) -> Iterator[TaskEnv]:
    env = checkpoint_env(checkpoint, sim, horizon)
    try:
        yield env
    finally:
        env.close()


def evaluate_checkpoint(
    checkpoint: Checkpoint,
    sim: SimName,
    seeds: Iterable[int],
    horizon: int | None = None,
    rnn_horizon: int | None = None,
    trace: bool = False,
    video: Path | None = None,
    video_episodes: int = 2,
) -> EvalReport:
    """A BC policy's rollouts, one per seed; ``video`` keeps the first ``video_episodes`` as
    an MP4."""
    from crowdteleop.learn.bc import Policy

    render_mode = "rgb_array" if video is not None else None
    env = checkpoint_env(checkpoint, sim, horizon, render_mode)
    try:
        return evaluate(
            Policy(checkpoint, rnn_horizon),
            env,
            seeds,
            trace,
            video,
            video_episodes,
        )
    finally:
        env.close()


# --- PPO runs (`learn rl`) ---


class PolicyRunner:
    """An sb3 recurrent model and its observation normalizer, acting deterministically on one
    environment, its LSTM state carried through the episode."""

    def __init__(self, model: BaseAlgorithm, normalizer: VecNormalize | None) -> None:
        self.model, self.normalizer = model, normalizer
        self.reset()

    def reset(self, seed: int = 0) -> None:
        self._state: tuple[npt.NDArray[np.float32], ...] | None = None
        self._start = np.ones((1,), dtype=bool)

    def act(self, obs: Observation) -> npt.NDArray[np.float32]:
        batched: npt.NDArray[np.generic] | dict[str, npt.NDArray[np.generic]]
        if isinstance(obs, dict):
            batched = {key: np.asarray(value)[None] for key, value in obs.items()}
        else:
            batched = np.asarray(obs)[None]
        if self.normalizer is not None:
            batched = self.normalizer.normalize_obs(batched)
        action, self._state = self.model.predict(
            batched, state=self._state, episode_start=self._start, deterministic=True
        )
        self._start = np.zeros((1,), dtype=bool)
        return np.asarray(action[0], dtype=np.float32)


def is_ppo_run(path: Path) -> bool:
    return (path / "model.zip").exists() or path.suffix == ".zip"


def run_directory(path: Path) -> Path:
    return path.parent if path.suffix == ".zip" else path


def load_runner(run: Path) -> tuple[PolicyRunner, dict[str, object]]:
    """The run's policy (``model.zip`` with ``vecnormalize.pkl``) and its ``run.json``."""
    import pickle

    from sb3_contrib import RecurrentPPO
    from stable_baselines3 import SAC

    info = json.loads((run / "run.json").read_text())
    algorithm = RecurrentPPO if info.get("algo") == "ppo" else SAC
    model = algorithm.load(str(run / "model.zip"), device="cpu")
    normalizer = None
    if (run / "vecnormalize.pkl").exists():
        with (run / "vecnormalize.pkl").open("rb") as file:
            normalizer = pickle.load(file)  # a VecNormalize without its venv
        normalizer.training = False
    return PolicyRunner(model, normalizer), info


def run_env(
    info: Mapping[str, object], sim: SimName, horizon: int, render_mode: str | None = None
) -> TaskEnv:
    """A PPO run's environment from its ``run.json``, normal resets only, ``horizon`` steps."""
    env = info.get("env")
    if not isinstance(env, Mapping):
        raise LearnDataError("run.json names no environment settings ('env')")
    settings = EnvSettings.model_validate(env).model_copy(
        # the paper's return counts every solved step, also of a run trained to stop at one
        update={"demo_reset_p": 0.0, "horizon": horizon, "terminate_on_success": False}
    )
    scene = None
    if sim == "robosuite":
        env_args = info.get("env_args")
        if not isinstance(env_args, Mapping) or not env_args:
            raise LearnDataError(
                "this run was trained without a dataset, so it names no env_args to rebuild "
                "plain robosuite from; evaluate it with --sim ours"
            )
        scene = robosuite_scene(env_args)
    return make_env(settings, sim=sim, scene=scene, render_mode=render_mode)


def evaluate_run(
    run: Path,
    sim: SimName,
    seeds: Iterable[int],
    horizon: int = EVAL_HORIZON,
    video: Path | None = None,
    video_episodes: int = 2,
) -> EvalReport:
    """A PPO run's policy from normal resets, one rollout per seed."""
    runner, info = load_runner(run)
    env = run_env(info, sim, horizon, "rgb_array" if video is not None else None)
    try:
        return evaluate(runner, env, seeds, video=video, video_episodes=video_episodes)
    finally:
        env.close()
