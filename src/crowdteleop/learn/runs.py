"""What a reinforcement-learning run's directory holds, for PPO and SAC alike: ``run.json``
(what was asked, `RunInfo`), ``state.json`` (steps and seconds so far), ``curve.csv`` (success
and return from normal resets every ``eval_every`` steps), ``progress.csv`` (sb3's log) and
the checkpoint; and how a run starts afresh or resumes from them."""

from __future__ import annotations

import csv
import json
import time
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import configure

from crowdteleop.learn.config import PPOConfig, SACConfig
from crowdteleop.learn.envs import EnvSettings, TaskEnv, make_env
from crowdteleop.learn.evaluation import PolicyRunner, evaluate

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

    @classmethod
    def of(
        cls,
        algo: str,
        settings: EnvSettings,
        config: PPOConfig | SACConfig,
        dataset: Path | None,
        env_args: dict[str, object] | None,
    ) -> RunInfo:
        return cls(
            algo,
            str(settings.sim_config["task"]),
            config.demos,
            config.seed,
            str(dataset) if dataset else None,
            settings.model_dump(mode="json"),
            config.model_dump(mode="json"),
            env_args,
        )


def begin_run(output: Path, resume: bool, info: RunInfo) -> dict[str, float]:
    """The steps and seconds a resumed run has behind it (``state.json``, when ``resume`` and
    a checkpoint exist); else ``{}`` after clearing an earlier run's logs and writing
    ``run.json``."""
    output.mkdir(parents=True, exist_ok=True)
    state_path = output / "state.json"
    if resume and state_path.exists() and (output / "model.zip").exists():
        return dict(json.loads(state_path.read_text()))
    for stale in ("curve.csv", "progress.csv"):
        (output / stale).unlink(missing_ok=True)
    (output / "run.json").write_text(json.dumps(asdict(info), indent=2))
    return {}


def learn_to_budget(
    model: BaseAlgorithm,
    settings: EnvSettings,
    config: PPOConfig | SACConfig,
    output: Path,
    state: dict[str, float],
    progress_bar: bool,
) -> None:
    """Trains ``model`` from where ``state`` left it to ``total_steps`` or ``budget_s``, logging
    to ``output`` (CSV, and TensorBoard where installed), the curve and checkpoints as it goes."""
    model.set_logger(configure(str(output), ["csv", *tensorboard_formats()]))
    done = int(state.get("steps", 0))
    curve = CurveCallback(settings, config, output, float(state.get("seconds", 0.0)), done)
    remaining = max(0, config.total_steps - done)
    warnings.filterwarnings("ignore", "rich is experimental")  # sb3's tqdm.rich bar
    if remaining:
        model.learn(
            remaining, callback=curve, reset_num_timesteps=not state, progress_bar=progress_bar
        )
    curve.checkpoint(model)


def tensorboard_formats() -> list[str]:
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
        config: PPOConfig | SACConfig,
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
