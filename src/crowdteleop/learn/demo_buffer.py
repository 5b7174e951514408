"""Demonstrations as an off-policy learner's transitions, and the replay buffer that mixes them
into every batch (RLPD's symmetric sampling: Ball, Smith, Kostrikov and Levine, "Efficient
Online Reinforcement Learning with Offline Data", ICML 2023).

A demo's transitions are the dataset's ``obs``, ``actions`` and ``next_obs`` (the observation
keys concatenated in order, as `learn.envs.TaskEnv` gives them), cut at its first solved step:
the reward is the task's sparse one, 1 on reaching a solved state and 0 before, and that step
ends the episode, as in the environment a run trains in (``terminate_on_success``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt
import torch
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from crowdteleop.learn.data import LearnDataError, demo_names, open_learn_dataset

Floats = npt.NDArray[np.float32]


@dataclass(frozen=True)
class DemoTransitions:
    """Every demo step as one transition, in rows."""

    obs: Floats  # (N, D)
    actions: Floats  # (N, A), clipped to the action space [-1, 1]
    next_obs: Floats  # (N, D)
    rewards: Floats  # (N,)
    dones: Floats  # (N,): 1 at each demo's first solved step, its last row here
    demos: int

    def __len__(self) -> int:
        return len(self.obs)


def load_demo_transitions(path: Path, limit: int, obs_keys: tuple[str, ...]) -> DemoTransitions:
    """The first ``limit`` demos of a built dataset (by their numbers, as demonstration-state
    resets take them); refuses a dataset without observations or with fewer demos."""
    with open_learn_dataset(path) as file:
        names = demo_names(file["data"])
        if limit > len(names):
            raise LearnDataError(f"{path} holds {len(names)} demonstrations; {limit} were asked")
        parts = [_demo(file["data"][name], name, obs_keys) for name in names[:limit]]
    columns = [np.concatenate(column).astype(np.float32) for column in zip(*parts, strict=True)]
    obs, actions, next_obs, rewards = columns
    return DemoTransitions(obs, np.clip(actions, -1.0, 1.0), next_obs, rewards, rewards, limit)


def _demo(group: h5py.Group, name: str, obs_keys: tuple[str, ...]) -> list[Floats]:
    for key in ("obs", "next_obs", "actions", "rewards"):
        if key not in group:
            raise LearnDataError(
                f"{name} has no {key!r}: rebuild the dataset with "
                "`crowdteleop dataset build ... --obs low-dim`"
            )
    missing = [key for key in obs_keys if key not in group["obs"]]
    if missing:
        raise LearnDataError(f"{name} lacks observation keys {missing}")
    rows = len(group["actions"])
    solved = np.flatnonzero(np.asarray(group["rewards"][()]) > 0)
    end = int(solved[0]) + 1 if len(solved) else rows  # a demo never solved keeps every step
    rewards = np.zeros(end, dtype=np.float32)
    rewards[-1] = float(len(solved) > 0)

    def stacked(obs: h5py.Group) -> Floats:
        return np.concatenate(
            [np.asarray(obs[key][:end], dtype=np.float32).reshape(end, -1) for key in obs_keys],
            axis=1,
        )

    return [
        stacked(group["obs"]),
        np.asarray(group["actions"][:end], dtype=np.float32),
        stacked(group["next_obs"]),
        rewards,
    ]


class DemoReplayBuffer(ReplayBuffer):
    """sb3's replay buffer, each batch drawn ``demo_fraction`` from the demonstrations (all of
    it while the run has no experience of its own) and the rest from the run's. The demos are
    given with `attach` after construction (sb3 builds its buffers itself) and are not saved
    with the buffer: a resumed run attaches them again."""

    demos: DemoTransitions | None = None
    demo_fraction: float = 0.5

    def attach(self, demos: DemoTransitions, fraction: float, seed: int) -> None:
        self.demos, self.demo_fraction = demos, fraction
        self._rng = np.random.default_rng(seed)

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> ReplayBufferSamples:
        demos = self.demos
        if demos is None:
            return super().sample(batch_size, env)
        own = self.size() > 0
        from_demos = round(batch_size * self.demo_fraction) if own else batch_size
        rows = self._rng.integers(len(demos), size=from_demos)
        parts = [self._rows(demos, rows)]
        if batch_size > from_demos:
            parts.append(super().sample(batch_size - from_demos, env))

        def joined(field: str) -> torch.Tensor:
            return torch.cat([getattr(part, field) for part in parts])

        return ReplayBufferSamples(
            observations=joined("observations"),
            actions=joined("actions"),
            next_observations=joined("next_observations"),
            dones=joined("dones"),
            rewards=joined("rewards"),
        )

    def demo_batch(self, batch_size: int) -> ReplayBufferSamples:
        """Demo transitions only (a behaviour-cloning step's batch)."""
        if self.demos is None:
            raise ValueError("no demonstrations attached")
        return self._rows(self.demos, self._rng.integers(len(self.demos), size=batch_size))

    def _rows(self, demos: DemoTransitions, rows: npt.NDArray[np.int64]) -> ReplayBufferSamples:
        def tensor(values: Floats) -> torch.Tensor:
            return torch.as_tensor(values[rows], device=self.device)

        return ReplayBufferSamples(
            observations=tensor(demos.obs),
            actions=tensor(demos.actions),
            next_observations=tensor(demos.next_obs),
            dones=tensor(demos.dones)[:, None],
            rewards=tensor(demos.rewards)[:, None],
        )

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        state.pop("demos", None)  # the dataset's, attached again on resume
        return state
