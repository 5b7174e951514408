"""Training environments as Ray actors: the paper trained with 32 distributed actors; this runs
``n_envs`` environments anywhere on a Ray cluster (``address``), or on a local one Ray starts.

Each actor holds one `learn.envs.TaskEnv` over our simulation and resets it itself when an
episode ends, as sb3's ``SubprocVecEnv`` workers do (the last observation goes back in
``terminal_observation``).
The demonstrations travel once, through Ray's object store.

Ray has no authentication and listens on every interface: run a cluster only where its ports
are private (docs/learning.md); the test runs it in a loopback-only network namespace.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, cast

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from stable_baselines3.common.vec_env.base_vec_env import (
    VecEnv,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)
from stable_baselines3.common.vec_env.subproc_vec_env import _stack_obs

from crowdteleop.learn.demo_states import DemoStates
from crowdteleop.learn.envs import Action, EnvSettings, Observation, make_env

if TYPE_CHECKING:
    from ray import ObjectRef
    from ray.actor import ActorHandle

StepReply = tuple[Observation, float, bool, dict[str, object]]


class EnvActor:
    """One environment in a Ray worker (wrapped by ``ray.remote`` at run time)."""

    def __init__(self, settings: EnvSettings, demos: DemoStates | None) -> None:
        self.env = make_env(settings, demos)

    def spaces(self) -> tuple[gym.Space[Observation], gym.Space[Action]]:
        return self.env.observation_space, self.env.action_space

    def reset(
        self, seed: int | None, options: dict[str, object]
    ) -> tuple[Observation, dict[str, object]]:
        return self.env.reset(seed=seed, options=options or None)

    def step(self, action: npt.NDArray[np.float32]) -> StepReply:
        obs, reward, terminated, truncated, info = self.env.step(action)
        done = terminated or truncated
        info["TimeLimit.truncated"] = truncated and not terminated
        if done:
            info["terminal_observation"] = obs
            obs, reset_info = self.env.reset()
            info["reset_info"] = reset_info
        return obs, float(reward), done, info

    def get_attr(self, name: str) -> object:
        return getattr(self.env, name)

    def set_attr(self, name: str, value: object) -> None:
        setattr(self.env, name, value)

    def call(self, name: str, args: tuple[object, ...], kwargs: dict[str, object]) -> object:
        return getattr(self.env, name)(*args, **kwargs)

    def close(self) -> None:
        self.env.close()


class RayVecEnv(VecEnv):
    """sb3's ``VecEnv`` over Ray actors, ``actor_cpus`` CPUs each."""

    def __init__(
        self,
        settings: EnvSettings,
        demos: DemoStates | None,
        n_envs: int,
        address: str | None = None,
        actor_cpus: float = 1.0,
    ) -> None:
        import ray

        self._started_ray = not ray.is_initialized()
        if self._started_ray:
            ray.init(address=address, include_dashboard=False, log_to_driver=False)
        cpus = float(ray.cluster_resources().get("CPU", 0.0))  # type: ignore[no-untyped-call]
        if n_envs * actor_cpus > cpus:
            self._shutdown()
            raise ValueError(
                f"{n_envs} environments of {actor_cpus} CPU each do not fit the Ray cluster's "
                f"{cpus:g} CPUs: lower --n-envs or add nodes (Ray would wait for them forever)"
            )
        remote = ray.remote(num_cpus=actor_cpus)(EnvActor)
        demos_ref = ray.put(demos)
        self._actors = [
            cast("ActorHandle[EnvActor]", remote.remote(settings, demos_ref)) for _ in range(n_envs)
        ]
        spaces = cast(
            "tuple[gym.Space[Observation], gym.Space[Action]]",
            ray.get(self._actors[0].spaces.remote()),
        )
        observation_space, action_space = spaces
        super().__init__(n_envs, observation_space, action_space)
        self._pending: list[ObjectRef[StepReply]] = []

    def reset(self) -> VecEnvObs:
        import ray

        replies: list[tuple[Observation, dict[str, object]]] = ray.get(
            [
                actor.reset.remote(self._seeds[i], self._options[i])
                for i, actor in enumerate(self._actors)
            ]
        )
        self.reset_infos = [info for _, info in replies]
        self._reset_seeds()
        self._reset_options()
        return _stack_obs([obs for obs, _ in replies], self.observation_space)

    def step_async(self, actions: npt.NDArray[Any]) -> None:
        self._pending = [a.step.remote(act) for a, act in zip(self._actors, actions, strict=True)]

    def step_wait(self) -> VecEnvStepReturn:
        import ray

        results = ray.get(self._pending)
        self._pending = []
        obs, rewards, dones, infos = zip(*results, strict=True)
        for i, info in enumerate(infos):
            if "reset_info" in info:
                self.reset_infos[i] = info.pop("reset_info")
        return (
            _stack_obs(list(obs), self.observation_space),
            np.array(rewards, dtype=np.float32),
            np.array(dones, dtype=bool),
            list(infos),
        )

    def close(self) -> None:
        import ray

        if self._pending:
            ray.get(self._pending)
        ray.get([actor.close.remote() for actor in self._actors])
        for actor in self._actors:
            ray.kill(actor)
        self._shutdown()

    def _shutdown(self) -> None:
        import ray

        if self._started_ray:
            ray.shutdown()

    def _targets(self, indices: VecEnvIndices) -> list[ActorHandle[EnvActor]]:
        return [self._actors[i] for i in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[object]:
        import ray

        return list(ray.get([a.get_attr.remote(attr_name) for a in self._targets(indices)]))

    def set_attr(self, attr_name: str, value: object, indices: VecEnvIndices = None) -> None:
        import ray

        ray.get([a.set_attr.remote(attr_name, value) for a in self._targets(indices)])

    def env_method(
        self,
        method_name: str,
        *method_args: object,
        indices: VecEnvIndices = None,
        **method_kwargs: object,
    ) -> list[object]:
        import ray

        calls = [
            a.call.remote(method_name, method_args, method_kwargs) for a in self._targets(indices)
        ]
        return list(ray.get(calls))

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper[Any, Any, Any, Any]], indices: VecEnvIndices = None
    ) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[npt.NDArray[np.uint8] | None]:
        return [
            image if isinstance(image, np.ndarray) else None for image in self.env_method("render")
        ]
