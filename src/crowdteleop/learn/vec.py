"""The training environments, stepped in parallel: in subprocesses (sb3's ``SubprocVecEnv``,
the default), inline (``DummyVecEnv``: least overhead on a small machine) or as Ray actors
(`crowdteleop.learn.ray_vec`, for the paper's many actors on a cluster)."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import gymnasium as gym
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecMonitor

from crowdteleop.learn.config import VecKind
from crowdteleop.learn.demo_states import DemoStates
from crowdteleop.learn.envs import Action, EnvSettings, Observation, make_env


def make_vec_env(
    settings: EnvSettings,
    demos: DemoStates | None,
    n_envs: int,
    kind: VecKind,
    seed: int,
    ray_address: str | None = None,
    ray_actor_cpus: float = 1.0,
) -> VecEnv:
    """``n_envs`` environments seeded ``seed, seed + 1, ...``, with episode statistics
    (``VecMonitor``: return, length, and whether the episode was solved)."""
    factories: list[Callable[[], gym.Env[Observation, Action]]] = [
        partial(make_env, settings, demos) for _ in range(n_envs)
    ]
    venv: VecEnv
    if kind != "dummy":
        # one built here first: a bad dataset or config fails with its own message, not as a
        # worker process dying ("connection reset") or a remote actor's traceback
        make_env(settings, demos).close()
    if kind == "ray":
        from crowdteleop.learn.ray_vec import RayVecEnv

        venv = RayVecEnv(settings, demos, n_envs, ray_address, ray_actor_cpus)
    elif kind == "subproc" and n_envs > 1:
        venv = SubprocVecEnv(factories, start_method="forkserver")
    else:
        venv = DummyVecEnv(factories)
    venv.seed(seed)
    return VecMonitor(venv, info_keywords=("success",))
