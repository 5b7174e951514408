"""robomimic's env_args and robosuite's env_info, typed (crowdteleop.provenance.env_args):
built from a simulation's settings, parsed back, written with exactly the keys they hold."""

from __future__ import annotations

import json

from crowdteleop.provenance.controllers import JointPosition, OscPose
from crowdteleop.provenance.env_args import EnvArgs
from crowdteleop.sim.config import SimConfig


def test_a_robosuite_task_names_robot_controller_rate_and_version():
    env_args = EnvArgs.of(SimConfig(task="lift", action_mode="osc-pose"), "1.5.2")
    written = env_args.model_dump(mode="json")
    assert list(written) == ["env_name", "type", "env_kwargs", "env_version"]
    assert (written["env_name"], written["type"], written["env_version"]) == ("Lift", 1, "1.5.2")
    assert list(written["env_kwargs"]) == ["robots", "controller_configs", "control_freq"]
    assert written["env_kwargs"]["controller_configs"]["body_parts"]["right"]["type"] == "OSC_POSE"
    assert env_args.arm == OscPose()
    joint = EnvArgs.of(SimConfig(task="lift", control_hz=10.0), "1.5.2")
    assert joint.arm == JointPosition.velocity_servo(1.5, 0.1)


def test_a_pure_mujoco_scene_says_only_its_name_and_robot():
    written = EnvArgs.of(SimConfig(task="mujoco-lift"), "1.5.2").model_dump(mode="json")
    assert written == {"env_name": "lift", "type": 1, "env_kwargs": {"robots": ["Sawyer"]}}


def test_keys_it_does_not_know_are_kept_and_none_is_added():
    recorded = {
        "env_name": "Lift",
        "env_kwargs": {"robots": "Panda", "placement_initializer": None, "control_freq": 20},
        "robomimic_note": "kept",
    }
    parsed = EnvArgs.model_validate_json(json.dumps(recorded))
    assert parsed.robots == ["Panda"] and parsed.controller is None
    assert parsed.model_dump(mode="json") == {"type": 1} | recorded


def test_episode_metadata_keeps_the_controllers_null_keys():
    """The recorder drops unset metadata fields (exclude_none); never a key robosuite reads."""
    from crowdteleop.control.config import ControlConfig
    from crowdteleop.recording.metadata import episode_metadata

    sim = SimConfig(task="lift", action_mode="osc-pose")
    record = episode_metadata(sim, ControlConfig(controller="osc"), "frontview", "<mujoco/>", 0)
    arm = record.to_record()["env_args"]["env_kwargs"]["controller_configs"]["body_parts"]["right"]
    assert arm["position_limits"] is None and arm["interpolation"] is None
    assert record.to_record()["env_args"] == record.env_args.model_dump(mode="json")


def test_a_dataset_adds_robomimics_rendering_and_env_info_leaves_it_out():
    env_args = EnvArgs.of(SimConfig(task="lift", action_mode="osc-pose"), "1.5.2")
    rendered = env_args.with_rendering([("agentview", 84, 64)]).env_kwargs.model_dump(mode="json")
    assert rendered["camera_names"] == ["agentview"]
    assert (rendered["camera_widths"], rendered["camera_heights"]) == ([84], [64])
    assert rendered["has_offscreen_renderer"] and not rendered["has_renderer"]
    info = env_args.with_rendering([("agentview", 84, 64)]).env_info()
    assert info == {
        "env_name": "Lift",
        "robots": ["Sawyer"],
        "controller_configs": env_args.model_dump(mode="json")["env_kwargs"]["controller_configs"],
    }
