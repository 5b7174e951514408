"""Bad input gets a clear error naming the problem, and the simulation keeps working."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
from pydantic import ValidationError

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.config import ControlConfig
from crowdteleop.control.teleoperator import Teleoperator
from crowdteleop.errors import (
    ConfigError,
    InvalidActionError,
    InvalidCommandError,
    InvalidResolutionError,
    InvalidStateError,
    UnknownCameraError,
    UnknownRobotError,
)
from crowdteleop.gl import render_backend_error
from crowdteleop.sim import SimConfig, make_simulation


def test_unknown_task_lists_the_known_ones():
    with pytest.raises(ValidationError, match=r"unknown task 'juggle'.*lift.*nut-assembly-round"):
        SimConfig(task="juggle")


def test_unknown_robot_lists_the_known_ones():
    with pytest.raises(UnknownRobotError, match=r"unknown robot 'R2D2'.*Sawyer.*Panda"):
        make_simulation(SimConfig(task="lift", robot="R2D2"))
    with pytest.raises(UnknownRobotError, match="mujoco-arm"):
        make_simulation(SimConfig(task="mujoco-lift", robot="Panda"))


def test_bad_config_values_are_rejected():
    with pytest.raises(ValidationError):
        SimConfig(control_hz=0)
    with pytest.raises(ValidationError):
        SimConfig(unknown_field=1)
    with pytest.raises(ValidationError):
        ControlConfig(controller="telepathy")


def test_unknown_camera_and_bad_resolutions(lift_sim):
    with pytest.raises(UnknownCameraError, match=r"'ceiling'.*frontview.*agentview"):
        lift_sim.render("ceiling", 320, 240)
    for width, height in [(0, 240), (320, -1), (5000, 240), (320.5, 240), (320, 4000)]:
        with pytest.raises(InvalidResolutionError):
            lift_sim.render("frontview", width, height)
    assert lift_sim.render("frontview", 64, 48).shape == (48, 64, 3)


def test_bad_actions_and_states_leave_the_simulation_usable(lift_sim):
    size = lift_sim.action_spec.size
    before = lift_sim.get_state()
    with pytest.raises(InvalidActionError, match="shape"):
        lift_sim.step(np.zeros(size + 1))
    with pytest.raises(InvalidActionError, match="NaN"):
        lift_sim.step(np.full(size, np.nan))
    with pytest.raises(InvalidStateError, match="shape"):
        lift_sim.set_state(np.zeros(3))
    assert np.array_equal(lift_sim.get_state(), before)
    lift_sim.step(np.zeros(size))  # still steps


def test_nan_and_degenerate_device_commands_are_rejected():
    with pytest.raises(InvalidCommandError, match="NaN"):
        DeviceCommand(position=np.array([0.0, np.nan, 0.0]))
    with pytest.raises(InvalidCommandError, match="zero length"):
        DeviceCommand(quaternion=np.zeros(4))
    with pytest.raises(InvalidCommandError, match="shape"):
        DeviceCommand(position=np.zeros(2))


def test_controller_and_action_mode_must_match(lift_sim):
    with pytest.raises(ConfigError, match="osc-pose"):
        Teleoperator(lift_sim, ControlConfig(controller="osc"))
    with pytest.raises(ConfigError, match="joint-velocity"):
        make_simulation(SimConfig(task="mujoco-lift", action_mode="osc-pose"))


def test_render_backend_error_names_the_debian_package(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", "osmesa")
    message = str(render_backend_error(RuntimeError("no context")))
    assert "libosmesa6" in message and "apt-get install" in message


def test_a_broken_gl_backend_fails_with_the_package_to_install():
    """A real failure: GLFW with no display cannot make a context."""
    script = (
        "from crowdteleop.sim import make_simulation, SimConfig\n"
        "sim = make_simulation(SimConfig(task='mujoco-lift'))\n"
        "sim.render('frontview', 64, 48)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "PYOPENGL_PLATFORM")}
    env["MUJOCO_GL"] = "glfw"
    run = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True)
    assert run.returncode != 0
    assert "RenderBackendError" in run.stderr and "libglfw3" in run.stderr


def test_importing_mujoco_before_crowdteleop_is_explained():
    """MuJoCo fixes its GL backend at import; the error says which import to move."""
    script = (
        "import mujoco\n"
        "from crowdteleop.sim import make_simulation, SimConfig\n"
        "make_simulation(SimConfig(task='mujoco-lift')).render('frontview', 64, 48)\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    env.pop("DISPLAY", None)
    run = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True)
    assert run.returncode != 0
    assert "Import crowdteleop before mujoco" in run.stderr
