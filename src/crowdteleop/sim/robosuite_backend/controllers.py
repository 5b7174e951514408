"""robosuite controller configs for our two action modes (kept beside the backend that uses them).

Both are stateless between control steps, which is what makes `set_state` exact: the next step
depends only on the MuJoCo state and the action.
"""

from __future__ import annotations

from typing import Any

from crowdteleop.sim.config import SimConfig
from crowdteleop.tasks import get_task


def arm_controller_config(config: SimConfig, control_dt: float) -> dict[str, Any]:
    """The arm part controller for `config.action_mode`.

    ``joint-velocity``: robosuite's JOINT_POSITION servo in delta mode, scaled so the action is
    a joint velocity in rad/s held over one control period (goal = q + qdot * dt). robosuite's
    own JOINT_VELOCITY controller keeps integral and derivative error between steps, so a
    restored state would not reproduce the next step.
    ``osc-pose``: robosuite's OSC_POSE exactly as its teleop devices use it.
    """
    if config.action_mode == "osc-pose":
        return {
            "type": "OSC_POSE",
            "input_max": 1,
            "input_min": -1,
            "output_max": [0.05, 0.05, 0.05, 0.5, 0.5, 0.5],
            "output_min": [-0.05, -0.05, -0.05, -0.5, -0.5, -0.5],
            "kp": 150,
            "damping_ratio": 1,
            "impedance_mode": "fixed",
            "kp_limits": [0, 300],
            "damping_ratio_limits": [0, 10],
            "position_limits": None,
            "orientation_limits": None,
            "uncouple_pos_ori": True,
            "input_type": "delta",
            "input_ref_frame": "base",
            "interpolation": None,
            "ramp_ratio": 0.2,
            "gripper": {"type": "GRIP"},
        }
    speed = config.max_joint_speed
    # The servo re-anchors its goal every control step, so its damping (kd = 2 sqrt(kp)) eats
    # into the commanded speed unless kp * dt is comparable to kd: kp = 1.5 / dt^2 keeps about
    # 60% of the commanded joint speed at any control rate (20 Hz: kp = 600).
    stiffness = 1.5 / control_dt**2
    return {
        "type": "JOINT_POSITION",
        "input_max": speed,
        "input_min": -speed,
        "output_max": speed * control_dt,
        "output_min": -speed * control_dt,
        "kp": stiffness,
        "damping_ratio": 1,
        "impedance_mode": "fixed",
        "kp_limits": [0, stiffness],
        "damping_ratio_limits": [0, 10],
        "qpos_limits": None,
        "input_type": "delta",
        "interpolation": None,
        "ramp_ratio": 0.2,
        "gripper": {"type": "GRIP"},
    }


def composite_controller_config(config: SimConfig, control_dt: float) -> dict[str, Any]:
    """robosuite's BASIC composite controller with our arm part on the right arm."""
    return {"type": "BASIC", "body_parts": {"right": arm_controller_config(config, control_dt)}}


def robosuite_env_kwargs(config: SimConfig) -> dict[str, Any]:
    """What `robosuite.make(env_name, **kwargs)` needs to rebuild this simulation's scene,
    robot and controller in plain robosuite (robomimic's ``env_args["env_kwargs"]``)."""
    return {
        "robots": [config.robot],
        "controller_configs": composite_controller_config(config, 1.0 / config.control_hz),
        "control_freq": config.control_hz,
        **get_task(config.task).env_kwargs,
    }
