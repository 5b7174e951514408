"""A trained PPO policy run closed loop, one episode at a time: in our simulation (`SimEnv`
with normal resets) or in plain robosuite rebuilt from the dataset's ``env_args`` alone. The
return is the paper's: 1 for every step the task is solved, so a policy that solves it at once
and holds it scores the horizon (1000 at the paper's evaluation horizon)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from crowdteleop.learn.rollout import make_plain_robosuite, reseed_plain

EVAL_HORIZON = 1000  # the paper's "maximum possible return ... is 1000"


class StepEnv(Protocol):
    """The Gymnasium calls an evaluation makes."""

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]: ...

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]: ...


@dataclass(frozen=True)
class PolicyOutcome:
    seed: int
    episode_return: float
    success: bool  # solved at any step
    first_success_step: int | None


class PolicyRunner:
    """An sb3 recurrent model and its observation normalizer, acting deterministically on one
    environment, its LSTM state carried through the episode."""

    def __init__(self, model: Any, normalizer: Any | None) -> None:
        self.model, self.normalizer = model, normalizer
        self.reset()

    def reset(self) -> None:
        self._state: Any = None
        self._start = np.ones((1,), dtype=bool)

    def act(self, obs: Any) -> npt.NDArray[np.float32]:
        batched = _batched(obs)
        if self.normalizer is not None:
            batched = self.normalizer.normalize_obs(batched)
        action, self._state = self.model.predict(
            batched, state=self._state, episode_start=self._start, deterministic=True
        )
        self._start = np.zeros((1,), dtype=bool)
        return np.asarray(action[0], dtype=np.float32)


def _batched(obs: Any) -> Any:
    if isinstance(obs, dict):
        return {key: np.asarray(value)[None] for key, value in obs.items()}
    return np.asarray(obs)[None]


def run_policy(
    env: StepEnv,
    runner: PolicyRunner,
    seed: int,
    horizon: int,
    frames: list[npt.NDArray[np.uint8]] | None = None,
) -> PolicyOutcome:
    """One episode of ``horizon`` steps from a normal reset (no early stop: the return counts
    how long the task stays solved); ``frames`` collects ``env.render()`` per step."""
    obs, _ = env.reset(seed=seed, options=None)
    runner.reset()
    total, first = 0.0, None
    for step in range(1, horizon + 1):
        obs, reward, terminated, _, info = env.step(runner.act(obs))
        total += float(reward)
        if info.get("success") and first is None:
            first = step
        if frames is not None:
            frames.append(env.render())  # type: ignore[attr-defined]
        if terminated:
            break
    return PolicyOutcome(seed, total, first is not None, first)


class PlainRobosuiteGym:
    """``robosuite.make(env_name, **env_kwargs)`` from a dataset's ``env_args`` (nothing of
    ours but the key renaming), observed with the same keys in the same order as `SimEnv`."""

    def __init__(self, env_args: dict[str, Any], obs_keys: tuple[str, ...]) -> None:
        self.env = make_plain_robosuite(env_args)
        low, high = self.env.action_spec
        self._low, self._high = np.asarray(low), np.asarray(high)
        self.obs_keys = obs_keys

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        if seed is not None:
            reseed_plain(self.env, seed)
        return self._flat(self.env.reset()), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        obs, _, _, _ = self.env.step(
            np.clip(np.asarray(action, dtype=float), self._low, self._high)
        )
        solved = bool(self.env._check_success())
        return self._flat(obs), float(solved), False, False, {"success": solved}

    def _flat(self, observables: dict[str, Any]) -> npt.NDArray[np.float32]:
        from crowdteleop.sim.types import low_dim_keys

        obs = low_dim_keys(observables)
        return np.concatenate(
            [np.asarray(obs[key], dtype=np.float32).reshape(-1) for key in self.obs_keys]
        )

    def close(self) -> None:
        self.env.close()
