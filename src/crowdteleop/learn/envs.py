"""One family of Gymnasium environments for learning and evaluation, over the two simulations a
dataset names:

- ``ours``: the platform's `Simulation` (the fast physics path), from the demos' recorded
  ``sim_config``; it alone can start episodes from demonstration states (`learn.demo_states`);
- ``robosuite``: plain ``robosuite.make(env_name, **env_kwargs)`` from the dataset's
  ``env_args`` alone, as a robomimic user would rebuild the scene.

Both are a `TaskEnv` with the same observation and action spaces: robosuite's low-dim keys
concatenated in a fixed order (float32), or with ``camera`` a dict of those (``low_dim``) and
an RGB image (``image``, uint8); actions are the dataset's, OSC pose deltas in [-1, 1] and the
gripper, or with ``actions="actions_abs"`` absolute hand targets (ours turns them into the
delta that sets the same goal, robosuite reads them with its own absolute OSC). The reward is
sparse, 1 at every step the task is solved, and ``info["success"]`` says so after every reset
and step. An episode is truncated after ``horizon`` steps, or with ``terminate_on_success``
ends at the first solved step.

Seeds: ``reset(seed=k)`` starts scene ``k`` in either simulation (ours: ``sim.reset(k)``;
robosuite: ``env.rng`` reseeded, from which it draws placements and joint noise); an unseeded
reset draws its scene from the environment's own generator. Plain robosuite's hard reset also
redraws the Lift cube's size from ``env.rng``, ours keeps the one drawn at construction, so
the same seed is the same scene within a simulation, not across the two.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, Protocol, SupportsFloat

import gymnasium as gym
import numpy as np
import numpy.typing as npt
from gymnasium import spaces
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from crowdteleop.errors import InvalidActionError
from crowdteleop.learn.actions import ActionKey
from crowdteleop.learn.config import STOCK_OBS_KEYS
from crowdteleop.learn.data import LearnDataError
from crowdteleop.learn.demo_states import DemoStates, StartState
from crowdteleop.provenance.controllers import CompositeController, OscPose
from crowdteleop.provenance.env_args import EnvArgs

if TYPE_CHECKING:
    from crowdteleop.dataset.absolute import AbsoluteTargets
    from crowdteleop.sim.interface import Simulation

SimName = Literal["ours", "robosuite"]
SIM_NAMES: tuple[SimName, ...] = ("ours", "robosuite")
PAPER_HORIZON = 100  # the paper's myopic horizon for training episodes
RENDER_SIZE = 256
# what plain robosuite takes where env_args is silent: headless, and episodes of any length
PLAIN_DEFAULTS: dict[str, object] = {
    "has_renderer": False,
    "has_offscreen_renderer": False,
    "use_camera_obs": False,
    "ignore_done": True,
}

Array = npt.NDArray[np.float64]
LowDim = npt.NDArray[np.float32]
Image = npt.NDArray[np.uint8]
Observation = LowDim | dict[str, LowDim | Image]
Action = npt.NDArray[np.float32] | npt.NDArray[np.float64]
NamedObs = dict[str, Array]  # robomimic's low-dim keys, as the simulation gives them


class EnvSettings(BaseModel):
    """What an environment is, beyond which simulation runs it: plain values, so a subprocess
    or a Ray actor can rebuild it, and a run writes it to ``run.json`` (read back with
    ``model_validate``; keys it does not know are ignored, keys it lacks take the defaults)."""

    model_config = ConfigDict(frozen=True, extra="ignore")

    sim_config: dict[str, object]  # ours: `SimConfig` fields (the demos' recorded ones)
    horizon: int = Field(PAPER_HORIZON, ge=1)
    obs_keys: tuple[str, ...] = Field(STOCK_OBS_KEYS, min_length=1)
    camera: str | None = None
    image_size: int = Field(84, ge=1)
    demo_reset_p: float = Field(0.9, ge=0, le=1, description="chance a reset starts in a demo")
    terminate_on_success: bool = False  # the paper's return counts every solved step
    actions: ActionKey = "actions"


@dataclass(frozen=True)
class RobosuiteScene:
    """What plain robosuite is rebuilt from: a dataset's typed ``env_args`` and, for an
    actions_abs policy, its ``actions_abs_controller_configs``."""

    env_args: EnvArgs
    abs_controller: CompositeController | None  # robosuite's OSC reading actions_abs

    @property
    def env_name(self) -> str:
        return self.env_args.env_name

    @property
    def env_kwargs(self) -> dict[str, object]:
        """robosuite.make's, with `PLAIN_DEFAULTS` where the dataset is silent."""
        return {**PLAIN_DEFAULTS, **self.env_args.robosuite_kwargs()}


def robosuite_scene(
    env_args: Mapping[str, object] | None,
    abs_controller_configs: Mapping[str, object] | None = None,
) -> RobosuiteScene:
    """robomimic's ``env_args`` (and the dataset's ``actions_abs_controller_configs``), read
    through the provenance layer; a clear error for what is not one of ours."""
    if not env_args:
        raise LearnDataError("the dataset has no env_args to rebuild plain robosuite from")
    try:
        typed = EnvArgs.model_validate(env_args)
        absolute = (
            CompositeController.model_validate(abs_controller_configs)
            if abs_controller_configs
            else None
        )
    except ValidationError as exc:
        raise LearnDataError(f"the dataset's env_args are not robosuite's: {exc}") from exc
    return RobosuiteScene(env_args=typed, abs_controller=absolute)


class Backend(Protocol):
    """One simulation as `TaskEnv` drives it."""

    cameras: tuple[str, ...]

    def action_space(self) -> spaces.Box: ...

    def reset(self, seed: int) -> None: ...

    def step(self, action: Array) -> None:
        """One control step with a finite action of the right size (bounds are the
        backend's to apply)."""

    def success(self) -> bool: ...

    def observations(self) -> NamedObs: ...

    def render(self, camera: str, width: int, height: int) -> Image: ...

    def close(self) -> None: ...


class TaskEnv(gym.Env[Observation, Action]):
    """A simulation as a Gymnasium environment; ``info`` holds ``success`` after every reset and
    step, and after a reset how the episode started (``start``: "normal" or "demo", with
    ``demo`` and ``step``). Build one with `make_env`."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 20}  # noqa: RUF012  (Gymnasium's)

    def __init__(
        self,
        name: SimName,
        backend: Backend,
        settings: EnvSettings,
        demos: DemoStates | None = None,
        render_mode: str | None = None,
    ) -> None:
        self.name, self.backend, self.settings = name, backend, settings
        self.demos = demos
        self.render_mode = render_mode
        self._dims = self._obs_dims()
        low_dim = spaces.Box(-np.inf, np.inf, shape=(sum(self._dims),), dtype=np.float32)
        self.observation_space: spaces.Space[Observation]
        if settings.camera is None:
            self.observation_space = low_dim
        else:
            if settings.camera not in backend.cameras:
                raise ValueError(f"no camera {settings.camera!r}; there are {backend.cameras}")
            size = settings.image_size
            image = spaces.Box(0, 255, shape=(size, size, 3), dtype=np.uint8)
            self.observation_space = spaces.Dict({"low_dim": low_dim, "image": image})  # type: ignore[assignment]
        self.action_space = backend.action_space()  # type: ignore[assignment]
        self._steps = 0

    @property
    def sim(self) -> Simulation:
        """Our `Simulation` (the ``ours`` backend only)."""
        if not isinstance(self.backend, OurSimulation):
            raise AttributeError(f"the {self.name} environment has no crowdteleop Simulation")
        return self.backend.sim

    def _obs_dims(self) -> tuple[int, ...]:
        obs = self.backend.observations()
        missing = [key for key in self.settings.obs_keys if key not in obs]
        if missing:
            raise ValueError(f"the simulation has no observation {missing}; it has {sorted(obs)}")
        return tuple(int(np.size(obs[key])) for key in self.settings.obs_keys)

    def reset(
        self, *, seed: int | None = None, options: dict[str, object] | None = None
    ) -> tuple[Observation, dict[str, object]]:
        """Scene ``seed`` (else one drawn from the environment's generator), or with
        probability ``demo_reset_p`` a demonstration's state; ``options={"start":
        StartState(...)}`` restores a chosen one."""
        super().reset(seed=seed)
        self._steps = 0
        start = (options or {}).get("start")
        if start is not None and not isinstance(start, StartState):
            raise TypeError(f"options['start'] must be a StartState, got {start!r}")
        demos = self.demos
        if start is None and demos and self.np_random.random() < self.settings.demo_reset_p:
            start = demos.draw(self.np_random)
        info: dict[str, object]
        if start is None:
            self.backend.reset(int(self.np_random.integers(2**31)) if seed is None else seed)
            info = {"start": "normal"}
        else:
            self.restore(start)
            info = {"start": "demo", "demo": start.demo, "step": start.step}
        info["success"] = self.backend.success()
        return self._observation(), info

    def restore(self, start: StartState) -> None:
        """The simulation exactly as it was at ``start`` (ours only)."""
        if self.demos is None or not isinstance(self.backend, OurSimulation):
            raise ValueError("this environment was given no demonstrations")
        self.backend.restore(self.demos, start)

    def step(
        self, action: Action
    ) -> tuple[Observation, SupportsFloat, bool, bool, dict[str, object]]:
        values = np.asarray(action, dtype=np.float64)
        size = self.action_space.shape
        if values.shape != size:
            raise InvalidActionError(f"action must have shape {size}, got {values.shape}")
        if not np.all(np.isfinite(values)):
            raise InvalidActionError("action contains NaN or infinity")
        self.backend.step(values)
        self._steps += 1
        solved = self.backend.success()
        terminated = solved and self.settings.terminate_on_success
        truncated = self._steps >= self.settings.horizon and not terminated
        return self._observation(), float(solved), terminated, truncated, {"success": solved}

    def render(self) -> Image | None:
        if self.render_mode != "rgb_array":
            return None
        camera = self.settings.camera or self.backend.cameras[0]
        return self.backend.render(camera, RENDER_SIZE, RENDER_SIZE)

    def named_observations(self) -> NamedObs:
        """The current low-dim observations by robomimic's key (all of them, float64)."""
        return self.backend.observations()

    def close(self) -> None:
        self.backend.close()

    def _observation(self) -> Observation:
        obs = self.backend.observations()
        low_dim: LowDim = np.concatenate(
            [np.asarray(obs[key], dtype=np.float32).reshape(-1) for key in self.settings.obs_keys]
        )
        if self.settings.camera is None:
            return low_dim
        size = self.settings.image_size
        return {"low_dim": low_dim, "image": self.backend.render(self.settings.camera, size, size)}


class OurSimulation:
    """The platform's simulation from ``sim_config``. A policy of absolute targets drives its
    delta OSC through `AbsoluteTargets.to_delta` (osc demos only)."""

    def __init__(
        self,
        settings: EnvSettings,
        demos: DemoStates | None = None,
        scene: RobosuiteScene | None = None,
    ) -> None:
        from crowdteleop.sim import SimConfig, make_simulation
        from crowdteleop.sim.mjcf import same_model

        if not settings.sim_config:
            raise LearnDataError("the dataset recorded no sim_config to rebuild our simulation")
        config = SimConfig.model_validate(settings.sim_config)
        if demos is not None and demos.sim_config != config.model_dump(mode="json"):
            raise ValueError("the demonstrations were recorded in another simulation config")
        self.sim = make_simulation(config)
        self.cameras = self.sim.cameras
        try:
            if demos is not None and not same_model(demos.demos[0].model_xml, self.sim.mjcf_xml()):
                raise ValueError(
                    "this crowdteleop / robosuite no longer builds the model the demonstrations "
                    "were recorded in; their states cannot be restored here"
                )
            self._targets = self._absolute_targets(settings, scene)
        except Exception:
            self.sim.close()
            raise

    def _absolute_targets(
        self, settings: EnvSettings, scene: RobosuiteScene | None
    ) -> AbsoluteTargets | None:
        from crowdteleop.dataset.absolute import AbsoluteTargets

        if settings.actions != "actions_abs":
            return None
        arm = scene.env_args.arm if scene is not None else None
        if not isinstance(arm, OscPose):
            raise LearnDataError(
                "an actions_abs policy rolls out in our simulation for osc demos only "
                f"(these were recorded with {arm.type if arm else 'an unknown controller'}); "
                "evaluate it with --sim robosuite"
            )
        return AbsoluteTargets(self.sim.kinematics(), arm)

    def action_space(self) -> spaces.Box:
        spec = self.sim.action_spec
        if self._targets is not None:  # [x, y, z, ax, ay, az, gripper], unbounded
            return spaces.Box(-np.inf, np.inf, shape=(spec.size,), dtype=np.float32)
        return spaces.Box(
            spec.low.astype(np.float32), spec.high.astype(np.float32), dtype=np.float32
        )

    def reset(self, seed: int) -> None:
        self.sim.reset(seed=seed)

    def restore(self, demos: DemoStates, start: StartState) -> None:
        """The episode's reset (robosuite's OSC keeps its first joint posture as the null-space
        target, outside the state), then the recorded state and controller state."""
        demo = demos.demos[start.demo]
        if demo.reset_seed is not None:
            self.sim.reset(seed=demo.reset_seed)
        self.sim.set_state(demo.states[start.step])
        if demo.controller_states.shape[1]:
            self.sim.set_controller_state(demo.controller_states[start.step])

    def step(self, action: Array) -> None:
        if self._targets is not None:
            action = self._targets.to_delta(self.sim.get_state(), action)
        spec = self.sim.action_spec
        self.sim.step(np.clip(action, spec.low, spec.high))

    def success(self) -> bool:
        return bool(self.sim.success())

    def observations(self) -> NamedObs:
        return self.sim.observations()

    def render(self, camera: str, width: int, height: int) -> Image:
        return self.sim.render(camera, width, height)

    def close(self) -> None:
        self.sim.close()


class PlainRobosuite:
    """``robosuite.make(env_name, **env_kwargs)`` and nothing of ours but the key renaming
    (`crowdteleop.sim.types.low_dim_keys`). An actions_abs policy gets the dataset's
    ``actions_abs_controller_configs`` instead (robosuite's OSC_POSE reading absolute targets
    in the base frame), unclipped: robosuite reports input_min / input_max (+-1) as its action
    spec, but its absolute OSC reads the pose as it is, and clipping would cut rotations past
    1 rad."""

    def __init__(self, settings: EnvSettings, scene: RobosuiteScene, render: bool = False) -> None:
        os.environ.setdefault("PYNPUT_BACKEND", "dummy")  # robosuite.devices wants a display
        import robosuite

        overrides: dict[str, object] = {}
        self._absolute = settings.actions == "actions_abs"
        if self._absolute:
            if scene.abs_controller is None:
                raise LearnDataError("the dataset named no actions_abs_controller_configs")
            overrides["controller_configs"] = scene.abs_controller.to_robosuite()
        if render or settings.camera is not None:
            overrides["has_offscreen_renderer"] = True
        self.env = robosuite.make(scene.env_name, **{**scene.env_kwargs, **overrides})
        self.cameras: tuple[str, ...] = tuple(self.env.sim.model.camera_names)
        low, high = self.env.action_spec
        self._low, self._high = (
            np.asarray(low, dtype=np.float64),
            np.asarray(high, dtype=np.float64),
        )
        self._obs = dict(self.env.observation_spec())

    def action_space(self) -> spaces.Box:
        if self._absolute:
            return spaces.Box(-np.inf, np.inf, shape=self._low.shape, dtype=np.float32)
        return spaces.Box(
            self._low.astype(np.float32), self._high.astype(np.float32), dtype=np.float32
        )

    def reset(self, seed: int) -> None:
        # in place: robosuite's placement samplers hold a reference to env.rng
        self.env.rng.bit_generator.state = np.random.default_rng(seed).bit_generator.state
        self.env.reset()
        # robosuite's reset empties its observation cache, and an object-to-hand sensor reads
        # the object's pose from that cache before the object's own sensor refills it: the
        # first observation's e.g. Can_to_robot0_eef_pos is zeros (pick-place, not lift), an
        # input no training step has. Asked again, robosuite gives the scene's, as ours does.
        self._obs = dict(self.env._get_observations(force_update=True))

    def step(self, action: Array) -> None:
        if not self._absolute:
            action = np.clip(action, self._low, self._high)
        self._obs = dict(self.env.step(action)[0])

    def success(self) -> bool:
        # robosuite has no public success test: its step's info is empty, and its reward says
        # success only under sparse, unscaled settings env_args may change. robomimic's own
        # EnvRobosuite.is_success calls the same private method.
        return bool(self.env._check_success())

    def observations(self) -> NamedObs:
        from crowdteleop.sim.types import low_dim_keys

        return low_dim_keys(self._obs)

    def render(self, camera: str, width: int, height: int) -> Image:
        frame = self.env.sim.render(camera_name=camera, width=width, height=height)
        return np.ascontiguousarray(frame[::-1], dtype=np.uint8)  # MuJoCo's rows run bottom-up

    def close(self) -> None:
        self.env.close()


def make_env(
    settings: EnvSettings,
    demos: DemoStates | None = None,
    *,
    sim: SimName = "ours",
    scene: RobosuiteScene | None = None,
    render_mode: str | None = None,
) -> TaskEnv:
    """The environment ``settings`` describe, in our simulation or plain robosuite (which
    needs ``scene``, and starts no episode from demonstrations). Everything is picklable, so a
    vectorised runner can call it in a fresh process."""
    backend: Backend
    if sim == "ours":
        backend = OurSimulation(settings, demos, scene)
    else:
        if demos is not None:
            raise ValueError("plain robosuite cannot start episodes from demonstration states")
        if scene is None:
            raise LearnDataError("the dataset has no env_args to rebuild plain robosuite from")
        backend = PlainRobosuite(settings, scene, render=render_mode is not None)
    try:
        return TaskEnv(sim, backend, settings, demos, render_mode)
    except Exception:
        backend.close()
        raise


__all__ = [
    "PAPER_HORIZON",
    "EnvSettings",
    "RobosuiteScene",
    "SimName",
    "StartState",
    "TaskEnv",
    "make_env",
    "robosuite_scene",
]
