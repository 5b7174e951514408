"""Demonstration-guided PPO (the paper's Sec. 5 and Appendix): sb3-contrib's ``RecurrentPPO``
with the paper's networks, over our simulation (`learn.envs`) with demonstration-state resets.

A run directory holds what every RL run's does (`learn.runs`), its checkpoint being
``model.zip`` and ``vecnormalize.pkl``. Run it again with ``resume`` to continue from it.
"""

from __future__ import annotations

from pathlib import Path

import torch
from sb3_contrib import RecurrentPPO
from stable_baselines3.common.vec_env import VecEnv, VecNormalize

from crowdteleop.learn.config import PPOConfig
from crowdteleop.learn.demo_states import DemoStates
from crowdteleop.learn.envs import EnvSettings
from crowdteleop.learn.ppo_policy import LstmPolicy, MultiInputLstmPolicy
from crowdteleop.learn.runs import RunInfo, begin_run, learn_to_budget
from crowdteleop.learn.vec import make_vec_env


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
    torch.set_num_threads(config.threads)
    state = begin_run(output, resume, RunInfo.of("ppo", settings, config, dataset, env_args))
    model_path, norm_path = output / "model.zip", output / "vecnormalize.pkl"
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
        venv = normalized_env(venv, config, norm_path if state else None)
        model = _model(config, venv, model_path if state else None)
        learn_to_budget(model, settings, config, output, state, progress_bar)
    finally:
        venv.close()
    return model_path


def normalized_env(venv: VecEnv, config: PPOConfig, saved: Path | None) -> VecEnv:
    """The environments behind sb3's running normalizer of observations and/or rewards; the
    reward scale uses the run's own discount, as the returns it estimates do."""
    if not (config.normalize_obs or config.normalize_reward):
        return venv
    if saved is not None and saved.exists():
        loaded = VecNormalize.load(str(saved), venv)
        loaded.training = True
        return loaded
    return VecNormalize(
        venv,
        norm_obs=config.normalize_obs,
        norm_reward=config.normalize_reward,
        clip_obs=10.0,
        gamma=config.gamma,
    )


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
