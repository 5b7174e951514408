"""A Gymnasium environment over the platform's `Simulation` (the fast physics path, not plain
robosuite), set up as the paper's learning experiments: a sparse reward of 1 at every step the
task is solved (no shaping), a myopic 100-step horizon for training episodes, and, with
demonstrations, episodes that start from states drawn out of them.

Observations are robosuite's low-dimensional keys concatenated in a fixed order (float32), or
with ``camera`` a dict of those (``low_dim``) and an RGB image (``image``, uint8 HxWx3).
Actions are the simulation's own (``ActionSpec``): OSC pose deltas in [-1, 1] or joint
velocities, then the gripper.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces

from crowdteleop.learn.config import STOCK_OBS_KEYS
from crowdteleop.learn.demo_states import DemoStates, StartState
from crowdteleop.sim.config import SimConfig
from crowdteleop.sim.mjcf import same_model

PAPER_HORIZON = 100  # the paper's myopic horizon for training episodes


@dataclass(frozen=True)
class EnvSettings:
    """What an environment is, beyond its simulation: plain values, so a subprocess or a Ray
    actor can rebuild the same environment from them."""

    sim_config: dict[str, Any]
    horizon: int = PAPER_HORIZON
    obs_keys: tuple[str, ...] = STOCK_OBS_KEYS
    camera: str | None = None
    image_size: int = 84
    demo_reset_p: float = 0.9
    terminate_on_success: bool = False  # the paper's return counts every solved step


class SimEnv(gym.Env[Any, npt.NDArray[np.float32]]):
    """One simulation as a Gymnasium environment; ``info`` says how each episode started
    (``start``: "normal" or "demo", with ``demo`` and ``step``) and whether it is solved."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012  (Gymnasium's)

    def __init__(
        self,
        settings: EnvSettings,
        demos: DemoStates | None = None,
        render_mode: str | None = None,
    ) -> None:
        from crowdteleop.sim import make_simulation

        if not 0.0 <= settings.demo_reset_p <= 1.0:
            raise ValueError(f"demo_reset_p must be in [0, 1], got {settings.demo_reset_p}")
        if demos is not None and demos.sim_config != _normalized(settings.sim_config):
            raise ValueError("the demonstrations were recorded in another simulation config")
        self.settings = settings
        self.demos = demos
        self.render_mode = render_mode
        self.sim = make_simulation(SimConfig(**settings.sim_config))
        if demos is not None and not same_model(demos.demos[0].model_xml, self.sim.mjcf_xml()):
            self.sim.close()
            raise ValueError(
                "this crowdteleop / robosuite no longer builds the model the demonstrations were "
                "recorded in; their states cannot be restored here"
            )
        self._dims = self._obs_dims()
        low_dim = spaces.Box(-np.inf, np.inf, shape=(sum(self._dims),), dtype=np.float32)
        if settings.camera is None:
            self.observation_space = low_dim
        else:
            if settings.camera not in self.sim.cameras:
                raise ValueError(f"no camera {settings.camera!r}; there are {self.sim.cameras}")
            size = settings.image_size
            image = spaces.Box(0, 255, shape=(size, size, 3), dtype=np.uint8)
            self.observation_space = spaces.Dict({"low_dim": low_dim, "image": image})
        spec = self.sim.action_spec
        self.action_space = spaces.Box(
            spec.low.astype(np.float32), spec.high.astype(np.float32), dtype=np.float32
        )
        self._steps = 0

    def _obs_dims(self) -> tuple[int, ...]:
        obs = self.sim.observations()
        missing = [key for key in self.settings.obs_keys if key not in obs]
        if missing:
            raise ValueError(f"the simulation has no observation {missing}; it has {sorted(obs)}")
        return tuple(int(np.size(obs[key])) for key in self.settings.obs_keys)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """A normal reset, or with probability ``demo_reset_p`` a demonstration's state;
        ``options={"start": StartState(...)}`` restores a chosen one."""
        super().reset(seed=seed)
        self._steps = 0
        start = (options or {}).get("start")
        demos = self.demos
        if start is None and demos and self.np_random.random() < self.settings.demo_reset_p:
            start = demos.draw(self.np_random)
        if start is None:
            self.sim.reset(seed=int(self.np_random.integers(2**31)))
            info: dict[str, Any] = {"start": "normal"}
        else:
            self.restore(start)
            info = {"start": "demo", "demo": start.demo, "step": start.step}
        info["success"] = bool(self.sim.success())
        return self._observation(), info

    def restore(self, start: StartState) -> None:
        """The simulation exactly as it was at ``start``: the episode's reset (for robosuite's
        OSC null-space posture), then the recorded state and controller state."""
        if self.demos is None:
            raise ValueError("this environment was given no demonstrations")
        demo = self.demos.demos[start.demo]
        if demo.reset_seed is not None:
            self.sim.reset(seed=demo.reset_seed)
        self.sim.set_state(demo.states[start.step])
        if demo.controller_states.shape[1]:
            self.sim.set_controller_state(demo.controller_states[start.step])

    def step(
        self, action: npt.NDArray[np.float32]
    ) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        spec = self.sim.action_spec
        result = self.sim.step(np.clip(np.asarray(action, dtype=np.float64), spec.low, spec.high))
        self._steps += 1
        solved = bool(result.success)
        terminated = solved and self.settings.terminate_on_success
        truncated = self._steps >= self.settings.horizon and not terminated
        return self._observation(), float(solved), terminated, truncated, {"success": solved}

    def render(self) -> npt.NDArray[np.uint8] | None:
        if self.render_mode != "rgb_array":
            return None
        camera = self.settings.camera or self.sim.cameras[0]
        return self.sim.render(camera, 256, 256)

    def close(self) -> None:
        self.sim.close()

    def _observation(self) -> Any:
        obs = self.sim.observations()
        low_dim = np.concatenate(
            [np.asarray(obs[key], dtype=np.float32).reshape(-1) for key in self.settings.obs_keys]
        )
        if self.settings.camera is None:
            return low_dim
        size = self.settings.image_size
        return {"low_dim": low_dim, "image": self.sim.render(self.settings.camera, size, size)}


def _normalized(sim_config: dict[str, Any]) -> dict[str, Any]:
    return SimConfig.from_recorded(sim_config).model_dump(mode="json")


def make_env(settings: EnvSettings, demos: DemoStates | None = None) -> SimEnv:
    """A factory a vectorised runner can call in a fresh process (everything is picklable)."""
    return SimEnv(settings, demos)


__all__ = ["PAPER_HORIZON", "EnvSettings", "SimEnv", "StartState", "make_env"]
