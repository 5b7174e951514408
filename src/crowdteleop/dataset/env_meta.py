"""What a dataset says about the environment that made it, in the field's own words.

``env_args`` is robomimic's (``create_env_from_metadata`` builds plain robosuite from it alone);
``env_info`` is robosuite's (its playback script calls ``robosuite.make(**env_info, ...)``).
Both name the controller config, so recorded actions are read as the platform meant them.
"""

from __future__ import annotations

from typing import Any

from crowdteleop.dataset.observations import ObsSpec


def dataset_env_args(first: Any, obs: ObsSpec) -> dict[str, Any]:
    """robomimic's ``env_args`` for the dataset: as recorded when the recording named its
    controller, else derived from its ``sim_config``; with robomimic's rendering settings."""
    from crowdteleop.dataset.replay import recorded_env_args

    recorded = first.env_args or {}
    env_args = dict(recorded)
    if "controller_configs" not in recorded.get("env_kwargs", {}) and first.info.sim_config:
        env_args = recorded_env_args(first)
    kwargs = dict(env_args.get("env_kwargs", {}))
    kwargs.update(
        has_renderer=False,
        has_offscreen_renderer=bool(obs.images),
        ignore_done=True,
        use_object_obs=True,
        use_camera_obs=bool(obs.images),
        reward_shaping=False,
        camera_depths=False,
    )
    if obs.images:
        kwargs.update(
            camera_names=[image.camera for image in obs.images],
            camera_heights=[image.height for image in obs.images],
            camera_widths=[image.width for image in obs.images],
        )
    return env_args | {"env_kwargs": kwargs}


def env_info(env_args: dict[str, Any]) -> dict[str, Any]:
    """robosuite's ``env_info`` as its collector writes it (``env_name``, ``robots``,
    ``controller_configs``, the task's own arguments): its playback script calls
    ``robosuite.make(**env_info, has_renderer=..., control_freq=20, ...)``, so the arguments it
    passes itself are left out."""
    passed_by_playback = {
        "has_renderer",
        "has_offscreen_renderer",
        "ignore_done",
        "use_camera_obs",
        "reward_shaping",
        "control_freq",
    }
    rendering = {"use_object_obs", "camera_depths", "camera_names", "camera_heights"}
    skipped = passed_by_playback | rendering | {"camera_widths"}
    kwargs = env_args.get("env_kwargs", {})
    return {"env_name": env_args.get("env_name", "")} | {
        k: v for k, v in kwargs.items() if k not in skipped
    }
