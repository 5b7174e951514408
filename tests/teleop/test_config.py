"""The teleop server's configuration (crowdteleop.teleop.config): what cannot run is refused."""

from __future__ import annotations

import pytest

from crowdteleop.teleop.config import LimitsConfig, TeleopConfig, VideoConfig


def test_configs_refuse_what_aiortc_would_clamp_or_the_sim_could_not_run():
    with pytest.raises(ValueError, match="bitrates"):
        VideoConfig(codec="h264", min_bitrate_bps=250_000)
    with pytest.raises(ValueError, match="connect_timeout_s"):
        LimitsConfig(connect_timeout_s=0)
    with pytest.raises(ValueError, match="action mode"):
        TeleopConfig.model_validate(
            {"control": {"controller": "osc"}, "sim": {"action_mode": "joint-velocity"}}
        )
    # named once: the simulation's action mode follows the controller
    assert TeleopConfig.model_validate({"control": {"controller": "osc"}}).sim.action_mode == (
        "osc-pose"
    )
