"""``learn eval`` for a PPO run: its final policy from normal resets, in our simulation and in
plain robosuite (``env_args`` alone), the paper's return (solved steps out of the horizon) and
success rate, and an MP4 of the first rollouts in ours."""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from crowdteleop.learn.gym_env import EnvSettings, SimEnv
from crowdteleop.learn.policy_eval import (
    EVAL_HORIZON,
    PlainRobosuiteGym,
    PolicyOutcome,
    PolicyRunner,
    StepEnv,
    run_policy,
)

SimName = Literal["ours", "robosuite"]


@dataclass(frozen=True)
class RLEvalReport:
    sim: SimName
    horizon: int
    episodes: list[PolicyOutcome]
    seconds: float

    def summary(self) -> dict[str, Any]:
        returns = [e.episode_return for e in self.episodes]
        return {
            "sim": self.sim,
            "episodes": len(self.episodes),
            "successes": sum(e.success for e in self.episodes),
            "success_rate": float(np.mean([e.success for e in self.episodes])),
            "mean_return": float(np.mean(returns)),
            "std_return": float(np.std(returns)),
            "horizon": self.horizon,
            "seconds": round(self.seconds, 1),
            "per_episode": [asdict(e) for e in self.episodes],
        }


def is_ppo_run(path: Path) -> bool:
    return (path / "model.zip").exists() or path.suffix == ".zip"


def run_directory(path: Path) -> Path:
    return path.parent if path.suffix == ".zip" else path


def load_runner(run: Path) -> tuple[PolicyRunner, dict[str, Any]]:
    """The run's policy (``model.zip`` with ``vecnormalize.pkl``) and its ``run.json``."""
    import pickle

    from sb3_contrib import RecurrentPPO

    info = json.loads((run / "run.json").read_text())
    model = RecurrentPPO.load(str(run / "model.zip"), device="cpu")
    normalizer = None
    if (run / "vecnormalize.pkl").exists():
        with (run / "vecnormalize.pkl").open("rb") as file:
            normalizer = pickle.load(file)  # a VecNormalize without its venv
        normalizer.training = False
    return PolicyRunner(model, normalizer), info


def evaluate_run(
    run: Path,
    sim: SimName,
    episodes: int,
    horizon: int = EVAL_HORIZON,
    seed: int = 1000,
    video: Path | None = None,
    video_episodes: int = 2,
) -> RLEvalReport:
    """``episodes`` rollouts with seeds ``seed, seed + 1, ...`` from normal resets."""
    runner, info = load_runner(run)
    env_fields = {**info["env"], "obs_keys": tuple(info["env"]["obs_keys"])}
    settings = replace(EnvSettings(**env_fields), demo_reset_p=0.0, horizon=horizon)
    env: StepEnv
    if sim == "ours":
        env = SimEnv(settings, render_mode="rgb_array")
    else:
        env_args = _env_args(info)
        env = PlainRobosuiteGym(env_args, tuple(settings.obs_keys))
    started = time.perf_counter()
    outcomes = []
    clips: list[Any] = []
    try:
        for k in range(episodes):
            frames: list[Any] | None = (
                [] if video and sim == "ours" and k < video_episodes else None
            )
            outcomes.append(run_policy(env, runner, seed + k, horizon, frames))
            if frames:
                clips.extend(frames)
    finally:
        env.close()
    if video and clips:
        from crowdteleop.dataset.video import Mp4Writer

        with Mp4Writer(video, fps=20) as writer:
            for frame in clips:
                writer.write(frame)
    return RLEvalReport(sim, horizon, outcomes, time.perf_counter() - started)


def _env_args(info: dict[str, Any]) -> dict[str, Any]:
    """robomimic's ``env_args`` of the dataset the run trained with."""
    from crowdteleop.learn.data import LearnDataError

    if not info.get("env_args"):
        raise LearnDataError(
            "this run was trained without a dataset, so it names no env_args to rebuild plain "
            "robosuite from; evaluate it with --sim ours"
        )
    return dict(info["env_args"])
