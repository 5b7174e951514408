"""Demonstration-guided PPO (the paper's Sec. 5 and Appendix): sb3-contrib's ``RecurrentPPO``
with the paper's networks, over our simulation (`learn.envs`) with demonstration-state resets.

A run directory holds ``run.json`` (what was asked), ``model.zip`` and ``vecnormalize.pkl``
(the latest checkpoint), ``progress.csv`` (sb3's training log), ``curve.csv`` (the learning
curve: return and success from normal resets every ``eval_every`` steps) and ``state.json``
(steps and seconds so far). Run it again with ``resume`` to continue from the checkpoint.
"""

from __future__ import annotations

import csv
import json
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from sb3_contrib import RecurrentPPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from crowdteleop.learn.config import PPOConfig
from crowdteleop.learn.demo_states import DemoStates
from crowdteleop.learn.envs import EnvSettings, TaskEnv, make_env
from crowdteleop.learn.evaluation import PolicyRunner, evaluate
from crowdteleop.learn.ppo_policy import LstmPolicy, MultiInputLstmPolicy
from crowdteleop.learn.vec import make_vec_env

CURVE_FIELDS = ("steps", "seconds", "mean_return", "success_rate", "episodes")


@dataclass(frozen=True)
class RunInfo:
    """What ``learn table`` groups runs by, written once as ``run.json``."""

    algo: str
    task: str
    demos: int
    seed: int
    dataset: str | None
    env: dict[str, object]  # EnvSettings
    config: dict[str, object]  # PPOConfig
    env_args: dict[str, object] | None  # robomimic's, from the dataset: plain robosuite's scene


def train_ppo(
    config: PPOConfig,
    settings: EnvSettings,
    demos: DemoStates | None,
    output: Path,
    resume: bool = False,
    progress_bar: bool = False,
    dataset: Path | None = None,
    env_args: dict[str, object] | None = None,
) -> Path:
    """Trains until ``config.total_steps`` (or ``budget_s``); returns the checkpoint's path.
    With ``resume``, a run that has a checkpoint continues from it (its steps and seconds
    count toward the budget); one without starts afresh."""
    output.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(config.threads)
    model_path, norm_path, state_path = (
        output / "model.zip",
        output / "vecnormalize.pkl",
        output / "state.json",
    )
    resuming = resume and state_path.exists() and model_path.exists()
    state = json.loads(state_path.read_text()) if resuming else {}
    if not state:
        for stale in ("curve.csv", "progress.csv"):
            (output / stale).unlink(missing_ok=True)
        info = RunInfo(
            "ppo",
            str(settings.sim_config["task"]),
            config.demos,
            config.seed,
            str(dataset) if dataset else None,
            settings.model_dump(mode="json"),
            config.model_dump(mode="json"),
            env_args,
        )
        (output / "run.json").write_text(json.dumps(asdict(info), indent=2))
    venv = make_vec_env(
        settings,
        demos,
        config.n_envs,
        config.vec,
        config.seed,
        config.ray_address,
        config.ray_actor_cpus,
    )
    try:
        venv = _normalized(venv, config, norm_path if state else None)
        model = _model(config, venv, model_path if state else None)
        model.set_logger(configure(str(output), ["csv"] + _tensorboard()))
        done = int(state.get("steps", 0))
        curve = CurveCallback(settings, config, output, float(state.get("seconds", 0.0)), done)
        remaining = max(0, config.total_steps - done)
        warnings.filterwarnings("ignore", "rich is experimental")  # sb3's tqdm.rich bar
        if remaining:
            model.learn(
                remaining,
                callback=curve,
                reset_num_timesteps=not state,
                progress_bar=progress_bar,
            )
        curve.checkpoint(model)
    finally:
        venv.close()
    return model_path


def _normalized(venv: VecEnv, config: PPOConfig, saved: Path | None) -> VecEnv:
    if not config.normalize_obs:
        return venv
    if saved is not None and saved.exists():
        loaded = VecNormalize.load(str(saved), venv)
        loaded.training = True
        return loaded
    return VecNormalize(venv, norm_obs=True, norm_reward=False, clip_obs=10.0)


def _model(config: PPOConfig, venv: VecEnv, saved: Path | None) -> RecurrentPPO:
    if saved is not None:
        return RecurrentPPO.load(str(saved), env=venv, device="cpu")
    arch = list(config.net_arch)
    policy = MultiInputLstmPolicy if _has_image(venv) else LstmPolicy
    return RecurrentPPO(
        policy,
        venv,
        n_steps=config.n_steps,
        batch_size=config.batch_size,
        n_epochs=config.n_epochs,
        learning_rate=config.learning_rate,
        gamma=config.gamma,
        gae_lambda=config.gae_lambda,
        clip_range=config.clip_range,
        ent_coef=config.ent_coef,
        seed=config.seed,
        device="cpu",
        policy_kwargs={
            "lstm_hidden_size": config.lstm_hidden,
            "n_lstm_layers": 1,
            "shared_lstm": False,
            "enable_critic_lstm": True,  # the paper: the same network for actor and critic
            "net_arch": {"pi": arch, "vf": arch},
            "log_std_init": config.log_std_init,
        },
    )


def _has_image(venv: VecEnv) -> bool:
    return hasattr(venv.observation_space, "spaces")


def _tensorboard() -> list[str]:
    try:
        import tensorboard  # noqa: F401
    except ImportError:
        return []
    return ["tensorboard"]


class CurveCallback(BaseCallback):
    """Learning-curve points from normal resets, checkpoints, and the wall-time budget."""

    def __init__(
        self,
        settings: EnvSettings,
        config: PPOConfig,
        output: Path,
        seconds_before: float,
        steps_before: int,
    ) -> None:
        super().__init__()
        self.settings, self.config, self.output = settings, config, output
        self.seconds_before = seconds_before
        self.started = time.perf_counter()
        self.next_eval = steps_before + config.eval_every if steps_before else 0
        self.next_checkpoint = steps_before + config.checkpoint_every
        self._eval_env: TaskEnv | None = None

    def seconds(self) -> float:
        return self.seconds_before + time.perf_counter() - self.started

    def _on_step(self) -> bool:
        steps = self.num_timesteps
        if steps >= self.next_eval:
            self.record_curve_point(steps)
            self.next_eval = steps + self.config.eval_every
        if steps >= self.next_checkpoint:
            self.checkpoint(self.model)
            self.next_checkpoint = steps + self.config.checkpoint_every
        budget = self.config.budget_s
        return budget is None or self.seconds() < budget

    def record_curve_point(self, steps: int) -> None:
        if self._eval_env is None:
            self._eval_env = make_env(self.settings.model_copy(update={"demo_reset_p": 0.0}))
        runner = PolicyRunner(self.model, self.model.get_vec_normalize_env())
        rng = np.random.default_rng(10_000 + self.config.seed)
        seeds = [int(rng.integers(2**31)) for _ in range(self.config.eval_episodes)]
        report = evaluate(runner, self._eval_env, seeds)
        path = self.output / "curve.csv"
        new = not path.exists()
        with path.open("a", newline="") as file:
            writer = csv.writer(file)
            if new:
                writer.writerow(CURVE_FIELDS)
            writer.writerow(
                [
                    steps,
                    round(self.seconds(), 1),
                    report.mean_return,
                    report.success_rate,
                    len(report.episodes),
                ]
            )

    def checkpoint(self, model: BaseAlgorithm) -> None:
        model.save(str(self.output / "model.zip"))
        normalizer = model.get_vec_normalize_env()
        if normalizer is not None:
            normalizer.save(str(self.output / "vecnormalize.pkl"))
        state = {"steps": int(model.num_timesteps), "seconds": round(self.seconds(), 1)}
        (self.output / "state.json").write_text(json.dumps(state))

    def _on_training_end(self) -> None:
        if self._eval_env is not None:
            self._eval_env.close()
            self._eval_env = None
