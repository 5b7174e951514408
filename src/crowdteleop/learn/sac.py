"""SAC with demonstrations (`config.SACConfig`): the sample-efficient learner beside the
paper's PPO, in the same environments, reward and evaluation (`learn.runs`).

A run directory holds what a PPO run's does (``run.json`` with ``algo: "sac"``, ``model.zip``,
``progress.csv``, ``curve.csv``, ``state.json``) and ``replay_buffer.pkl``, the run's own
experience, so ``resume`` continues the same learner; the demos are read from the dataset again.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3 import SAC
from stable_baselines3.common.policies import ContinuousCritic
from stable_baselines3.common.preprocessing import get_action_dim
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, create_mlp
from stable_baselines3.common.type_aliases import PyTorchObs, ReplayBufferSamples, Schedule
from stable_baselines3.common.utils import polyak_update
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecMonitor
from stable_baselines3.sac.policies import SACPolicy
from torch import nn
from torch.nn import functional

from crowdteleop.learn.config import SACConfig
from crowdteleop.learn.demo_buffer import DemoReplayBuffer, DemoTransitions
from crowdteleop.learn.demo_states import DemoStates
from crowdteleop.learn.envs import EnvSettings, make_env
from crowdteleop.learn.runs import RunInfo, begin_run, learn_to_budget


@dataclass(frozen=True)
class Demonstrations:
    """What a SAC run takes of its demos: their transitions, for its buffer and cloning, and
    optionally their states, to start training episodes from."""

    transitions: DemoTransitions
    starts: DemoStates | None = None


class LayerNormCritic(ContinuousCritic):
    """sb3's twin Q networks with a LayerNorm after each hidden layer, RLPD's critic: without
    it, the actor chasing the critic's guesses about actions no demo took drove the estimates
    to 10 on lift (a return can be at most 1) and success from 100 % to 50 % in 20k steps."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        inputs = int(kwargs["features_dim"]) + get_action_dim(self.action_space)
        arch, activation = kwargs["net_arch"], kwargs.get("activation_fn", nn.ReLU)
        self.q_networks = []
        for index in range(self.n_critics):
            layers = create_mlp(inputs, 1, arch, activation, post_linear_modules=[nn.LayerNorm])
            network = nn.Sequential(*layers)
            self.add_module(f"qf{index}", network)
            self.q_networks.append(network)


class LayerNormSACPolicy(SACPolicy):
    """SAC's policy with `LayerNormCritic`; with ``imitation_bootstrap`` (IBRL, Hu et al.
    2023), also a frozen copy of the cloned actor (`imitation`) whose action is taken instead
    of the learner's wherever the critic values it higher, in training and in evaluation."""

    def __init__(self, *args: Any, imitation_bootstrap: bool = False, **kwargs: Any) -> None:
        self.imitation_bootstrap = imitation_bootstrap  # before super() builds the networks
        super().__init__(*args, **kwargs)

    def _build(self, lr_schedule: Schedule) -> None:
        super()._build(lr_schedule)
        self.imitation = self.make_actor(features_extractor=None)
        self.imitation.requires_grad_(False)

    def make_critic(
        self, features_extractor: BaseFeaturesExtractor | None = None
    ) -> ContinuousCritic:
        kwargs = self._update_features_extractor(self.critic_kwargs, features_extractor)
        return LayerNormCritic(**kwargs).to(self.device)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {
            **super()._get_constructor_parameters(),
            "imitation_bootstrap": self.imitation_bootstrap,
        }

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> torch.Tensor:
        action: torch.Tensor = self.actor(observation, deterministic)
        if not self.imitation_bootstrap:
            return action
        return self.better_of(observation, action, self.critic)[0]

    def better_of(
        self, observation: PyTorchObs, action: torch.Tensor, critic: ContinuousCritic
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Per row, the imitation's action or ``action``, whichever ``critic`` (the lower of
        its estimates) values higher; and where the imitation's was taken."""
        imitation = self.imitation(observation, deterministic=True)
        taken = lowest_q(critic, observation, imitation) > lowest_q(critic, observation, action)
        return torch.where(taken, imitation, action), taken


def lowest_q(
    critic: ContinuousCritic, observation: PyTorchObs, action: torch.Tensor
) -> torch.Tensor:
    """The lowest of the critic's estimates, a column."""
    return torch.cat(critic(observation, action), dim=1).min(dim=1, keepdim=True).values


class DemoSAC(SAC):
    """sb3's SAC whose actor waits ``warmup_steps`` for the critic, and, given demos, takes a
    behaviour-cloning step on a demo batch after each of its own (``bc_weight`` times the
    squared error of its mean action): the demonstrated behaviour stays while the critic's
    estimates are still poor far from the demos."""

    warmup_steps: int = 0
    bc_weight: float = 0.0
    actor_learning_rate: float | None = None  # None: the critic's
    max_return: float | None = None  # IBRL's TD targets clipped to [0, max_return]

    def _update_learning_rate(self, optimizers: Any) -> None:
        super()._update_learning_rate(optimizers)
        rate = self.actor_learning_rate
        if self.num_timesteps < self.warmup_steps:
            rate = 0.0
        if rate is not None:
            for group in self.actor.optimizer.param_groups:
                group["lr"] = rate

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        if self.bootstrapped.imitation_bootstrap:
            self._train_bootstrapped(gradient_steps, batch_size)
        else:
            super().train(gradient_steps, batch_size)
        buffer = self.replay_buffer
        if self.bc_weight <= 0 or not isinstance(buffer, DemoReplayBuffer) or buffer.demos is None:
            return
        if self.num_timesteps < self.warmup_steps:
            return
        for _ in range(gradient_steps):
            batch = buffer.demo_batch(batch_size)
            clone_step(self, batch.observations, batch.actions, self.bc_weight)

    @property
    def bootstrapped(self) -> LayerNormSACPolicy:
        if not isinstance(self.policy, LayerNormSACPolicy):
            raise TypeError(f"a DemoSAC's policy is a LayerNormSACPolicy, not {self.policy}")
        return self.policy

    def _train_bootstrapped(self, gradient_steps: int, batch_size: int) -> None:
        """SAC's update (`SAC.train`, with the fixed entropy weight) whose TD target takes, at
        the next state, the imitation's action where the target critic values it higher."""
        self.policy.set_training_mode(True)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])
        critic_losses, actor_losses, imitation_shares = [], [], []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            target, taken = self._bootstrapped_target(data)
            current = self.critic(data.observations, data.actions)
            critic_loss = 0.5 * torch.stack([functional.mse_loss(q, target) for q in current]).sum()
            _step(self.critic.optimizer, critic_loss)
            actions, log_prob = self.actor.action_log_prob(data.observations)
            lowest = lowest_q(self.critic, data.observations, actions)
            actor_loss = (self.ent_coef_tensor * log_prob.reshape(-1, 1) - lowest).mean()
            _step(self.actor.optimizer, actor_loss)
            polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
            critic_losses.append(critic_loss.item())
            actor_losses.append(actor_loss.item())
            imitation_shares.append(float(taken.float().mean()))
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/critic_loss", np.mean(critic_losses))
        self.logger.record("train/actor_loss", np.mean(actor_losses))
        self.logger.record("train/imitation_share", np.mean(imitation_shares))

    def _bootstrapped_target(self, data: ReplayBufferSamples) -> tuple[torch.Tensor, torch.Tensor]:
        with torch.no_grad():
            learner, log_prob = self.actor.action_log_prob(data.next_observations)
            chosen, taken = self.bootstrapped.better_of(
                data.next_observations, learner, self.critic_target
            )
            entropy = torch.where(taken, 0.0, -self.ent_coef_tensor * log_prob.reshape(-1, 1))
            next_q = lowest_q(self.critic_target, data.next_observations, chosen) + entropy
            target = data.rewards + (1 - data.dones) * self.gamma * next_q
            if self.max_return is not None:
                target = target.clamp(0.0, self.max_return)
            return target, taken


def _step(optimizer: torch.optim.Optimizer, loss: torch.Tensor) -> None:
    optimizer.zero_grad()
    loss.backward()  # type: ignore[no-untyped-call]  # torch leaves it untyped
    optimizer.step()


def clone_step(model: SAC, obs: torch.Tensor, actions: torch.Tensor, weight: float) -> float:
    """One gradient step of the actor's mean toward ``actions`` (squared error)."""
    mean, _, _ = model.actor.get_action_dist_params(obs)
    loss = weight * ((torch.tanh(mean) - actions) ** 2).mean()
    _step(model.actor.optimizer, loss)
    return float(loss.detach())


def pretrain_actor(model: SAC, demos: DemoTransitions, config: SACConfig) -> float:
    """Behaviour cloning before any interaction: the actor's mean fit to the demos' actions by
    squared error, its log-std pulled to ``bc_log_std``; the last batch's loss."""
    generator = torch.Generator().manual_seed(config.seed)
    obs, actions = torch.as_tensor(demos.obs), torch.as_tensor(demos.actions)
    optimizer = torch.optim.Adam(model.actor.parameters(), lr=config.bc_learning_rate)
    loss = torch.zeros(())
    for _ in range(config.bc_steps):
        rows = torch.randint(len(obs), (config.batch_size,), generator=generator)
        mean, log_std, _ = model.actor.get_action_dist_params(obs[rows])
        loss = ((torch.tanh(mean) - actions[rows]) ** 2).mean()
        loss = loss + 0.1 * ((log_std - config.bc_log_std) ** 2).mean()
        _step(optimizer, loss)
    return float(loss.detach())


def train_sac(
    config: SACConfig,
    settings: EnvSettings,
    demos: Demonstrations | None,
    output: Path,
    resume: bool = False,
    progress_bar: bool = False,
    dataset: Path | None = None,
    env_args: dict[str, object] | None = None,
) -> Path:
    """Trains until ``config.total_steps`` (or ``budget_s``); returns the checkpoint's path.
    With ``resume``, a run that has a checkpoint continues from it (its steps and seconds
    count toward the budget); one without starts afresh. With ``demos.starts``, a training
    episode begins in a demo's state with ``settings.demo_reset_p``, as the paper's PPO's do."""
    torch.set_num_threads(config.threads)
    algo = "ibrl" if config.imitation_bootstrap else "sac"  # with 0 demos, both plain SAC
    state = begin_run(output, resume, RunInfo.of(algo, settings, config, dataset, env_args))
    model_path, buffer_path = output / "model.zip", output / "replay_buffer.pkl"
    starts = demos.starts if demos is not None else None
    # VecMonitor: sb3 logs the training episodes' return (here, solved or not) only from it
    venv = VecMonitor(DummyVecEnv([lambda: make_env(settings, starts)]), info_keywords=("success",))
    try:
        model = _model(config, venv, model_path if state else None, buffer_path)
        if demos is not None:
            _attach(model, demos.transitions, config)
            if not state:
                pretrain_actor(model, demos.transitions, config)
                model.bootstrapped.imitation.load_state_dict(model.actor.state_dict())
        learn_to_budget(model, settings, config, output, state, progress_bar)
        model.save_replay_buffer(str(buffer_path))
    finally:
        venv.close()
    return model_path


def _model(config: SACConfig, venv: VecEnv, saved: Path | None, buffer: Path) -> DemoSAC:
    if saved is not None:
        model = DemoSAC.load(str(saved), env=venv, device="cpu")
        if buffer.exists():
            model.load_replay_buffer(str(buffer))
        return model
    with_demos = config.demos > 0
    model = DemoSAC(
        LayerNormSACPolicy,
        venv,
        learning_rate=config.learning_rate,
        buffer_size=config.buffer_size,
        batch_size=config.batch_size,
        learning_starts=0 if with_demos else config.learning_starts,
        gamma=config.gamma,
        tau=config.tau,
        ent_coef=config.ent_coef,
        replay_buffer_class=DemoReplayBuffer,
        seed=config.seed,
        device="cpu",
        policy_kwargs={
            "net_arch": list(config.net_arch),
            "imitation_bootstrap": config.imitation_bootstrap and with_demos,
        },
    )
    model.warmup_steps = config.warmup_steps if with_demos else 0
    model.bc_weight = config.bc_weight if with_demos else 0.0
    model.actor_learning_rate = config.actor_learning_rate
    model.max_return = config.max_return
    return model


def _attach(model: SAC, demos: DemoTransitions, config: SACConfig) -> None:
    buffer = model.replay_buffer
    if not isinstance(buffer, DemoReplayBuffer):
        raise TypeError(f"a SAC run's buffer is a DemoReplayBuffer, not {type(buffer).__name__}")
    buffer.attach(demos, config.demo_fraction, config.seed)
