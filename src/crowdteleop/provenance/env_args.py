"""robomimic's ``env_args`` and robosuite's ``env_info``, typed: what rebuilds a recording's
scene, robot and controller in plain robosuite.

`EnvArgs.of` builds them from a simulation's settings (the teleop session and the scripted rig
record them with every episode; the dataset tools derive them for recordings made before);
``EnvArgs.model_validate`` / ``model_validate_json`` parse them back from a file. Written back,
they hold exactly the keys they were given (robomimic's ``create_env_from_metadata`` and
robosuite's ``robosuite.make(**env_info)`` read them): a key this module does not know, such as
a task's own argument, is kept as it was.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar, Protocol

from pydantic import BaseModel, ConfigDict, Field, model_serializer

from crowdteleop.provenance.controllers import (
    ArmController,
    CompositeController,
    Number,
    arm_controller,
)
from crowdteleop.tasks import get_task
from crowdteleop.vocab import ActionMode

ROBOMIMIC_ROBOSUITE = 1  # robomimic's EnvType.ROBOSUITE_TYPE

# What robosuite's playback script passes to robosuite.make itself, and the rendering settings
# robomimic adds: robosuite's collector leaves them out of env_info.
NOT_IN_ENV_INFO = frozenset(
    {
        "has_renderer",
        "has_offscreen_renderer",
        "ignore_done",
        "use_camera_obs",
        "reward_shaping",
        "control_freq",
        "use_object_obs",
        "camera_depths",
        "camera_names",
        "camera_heights",
        "camera_widths",
    }
)


class SimSettings(Protocol):
    """What `env_args` needs of a simulation's settings (``crowdteleop.sim.config.SimConfig``,
    read through this protocol: provenance sits below ``sim``)."""

    @property
    def task(self) -> str: ...
    @property
    def robot(self) -> str: ...
    @property
    def action_mode(self) -> ActionMode: ...
    @property
    def control_hz(self) -> float: ...
    @property
    def max_joint_speed(self) -> float: ...
    @property
    def gripper_type(self) -> str | None: ...


class _AsWritten(BaseModel):
    model_config = ConfigDict(extra="allow", frozen=True)
    _always: ClassVar[frozenset[str]] = frozenset()  # written even when left at the default

    @model_serializer
    def _as_written(self) -> dict[str, Any]:
        """The keys this was given (or built with), in field order, then the unknown ones."""
        given = self.model_fields_set | self._always
        written = {name: getattr(self, name) for name in type(self).model_fields if name in given}
        return written | (self.model_extra or {})


class EnvKwargs(_AsWritten):
    """``robosuite.make(env_name, **env_kwargs)``'s arguments: robot, controller and control
    rate as recorded; in a dataset also robomimic's rendering settings. A task's own
    arguments are extras."""

    robots: list[str] | str = Field(default_factory=list)
    controller_configs: CompositeController | None = None
    control_freq: Number | None = None
    has_renderer: bool | None = None
    has_offscreen_renderer: bool | None = None
    ignore_done: bool | None = None
    use_object_obs: bool | None = None
    use_camera_obs: bool | None = None
    reward_shaping: bool | None = None
    camera_depths: bool | None = None
    camera_names: list[str] | None = None
    camera_heights: list[int] | None = None
    camera_widths: list[int] | None = None


class EnvArgs(_AsWritten):
    """robomimic's ``env_args`` (type 1: robosuite)."""

    _always = frozenset({"env_name", "type", "env_kwargs"})
    env_name: str
    type: int = ROBOMIMIC_ROBOSUITE
    env_kwargs: EnvKwargs = Field(default_factory=EnvKwargs)
    env_version: str | None = None

    @classmethod
    def of(cls, sim: SimSettings, env_version: str) -> EnvArgs:
        """What rebuilds ``sim``'s scene, robot and controller in plain robosuite (robosuite
        ``env_version``). The scene of a pure-MuJoCo task names no environment robosuite could
        make: its env_args say only the scene and the robot."""
        task = get_task(sim.task)
        if task.backend != "robosuite":
            return cls(env_name=task.env_name, env_kwargs=EnvKwargs(robots=[sim.robot]))
        arm = arm_controller(sim.action_mode, 1.0 / sim.control_hz, sim.max_joint_speed)
        gripper = {} if sim.gripper_type is None else {"gripper_types": sim.gripper_type}
        kwargs = EnvKwargs(
            robots=[sim.robot],
            controller_configs=CompositeController.of(arm),
            control_freq=sim.control_hz,
            **gripper,
            **task.env_kwargs,
        )
        return cls(env_name=task.env_name, env_kwargs=kwargs, env_version=env_version)

    @property
    def controller(self) -> CompositeController | None:
        """The recorded controller; None where robosuite would use its default."""
        return self.env_kwargs.controller_configs

    @property
    def arm(self) -> ArmController | None:
        return None if self.controller is None else self.controller.arm

    @property
    def robots(self) -> list[str]:
        robots = self.env_kwargs.robots
        return [robots] if isinstance(robots, str) else list(robots)

    def with_controller(self, controller: CompositeController) -> EnvArgs:
        """The same scene driven by ``controller`` (e.g. the absolute OSC of ``actions_abs``)."""
        kwargs = self.env_kwargs.model_copy(update={"controller_configs": controller})
        return self.model_copy(update={"env_kwargs": kwargs})

    def with_rendering(self, cameras: Sequence[tuple[str, int, int]] = ()) -> EnvArgs:
        """With robomimic's rendering settings: headless, object observations, and images from
        ``cameras`` (name, width, height) if any."""
        settings: dict[str, Any] = {
            "has_renderer": False,
            "has_offscreen_renderer": bool(cameras),
            "ignore_done": True,
            "use_object_obs": True,
            "use_camera_obs": bool(cameras),
            "reward_shaping": False,
            "camera_depths": False,
        }
        if cameras:
            settings |= {
                "camera_names": [name for name, _, _ in cameras],
                "camera_heights": [height for _, _, height in cameras],
                "camera_widths": [width for _, width, _ in cameras],
            }
        kwargs = self.env_kwargs.model_copy(update=settings)
        return self.model_copy(update={"env_kwargs": kwargs})

    def robosuite_kwargs(self, **overrides: Any) -> dict[str, Any]:
        """``robosuite.make(env_name, **this)``: the recorded arguments, ``overrides`` on top."""
        return self.env_kwargs.model_dump(mode="json") | overrides

    def env_info(self) -> dict[str, Any]:
        """robosuite's ``env_info`` as its collector writes it (``env_name``, ``robots``,
        ``controller_configs``, the task's own arguments): its playback script calls
        ``robosuite.make(**env_info, has_renderer=..., control_freq=20, ...)``, so the arguments
        it passes itself are left out."""
        kwargs = self.env_kwargs.model_dump(mode="json")
        return {"env_name": self.env_name} | {
            key: value for key, value in kwargs.items() if key not in NOT_IN_ENV_INFO
        }
