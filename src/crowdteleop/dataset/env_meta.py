"""What a dataset says about the environment that made it, in the field's own words.

``env_args`` is robomimic's (``create_env_from_metadata`` builds plain robosuite from it alone);
``env_info`` is robosuite's (its playback script calls ``robosuite.make(**env_info, ...)``).
Both name the controller config, so recorded actions are read as the platform meant them;
their format is `crowdteleop.provenance.env_args.EnvArgs`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from crowdteleop.dataset.observations import ObsSpec
from crowdteleop.provenance.env_args import EnvArgs

if TYPE_CHECKING:
    from crowdteleop.dataset.replay import Demo


def dataset_env_args(first: Demo, obs: ObsSpec) -> EnvArgs:
    """robomimic's ``env_args`` for the dataset: as recorded when the recording named its
    controller, else derived from its ``sim_config``; with robomimic's rendering settings."""
    from crowdteleop.dataset.replay import recorded_env_args

    env_args = first.env_args or EnvArgs(env_name="")
    if env_args.controller is None and first.info.sim_config:
        env_args = recorded_env_args(first)
    cameras = [(image.camera, image.width, image.height) for image in obs.images]
    return env_args.with_rendering(cameras)
