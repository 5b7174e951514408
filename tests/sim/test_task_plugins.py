"""Tasks the platform has never seen run on the robosuite backend: a plug-in's own environment
class and success test, robosuite tasks found generically, the fast path applied where it is
faithful and robosuite's own step where it is not; bad declarations fail clearly."""

from __future__ import annotations

import re
import sys

import numpy as np
import pytest

from crowdteleop.control.config import ControlConfig
from crowdteleop.control.scripted import ScriptedOperator, run_episode
from crowdteleop.control.teleoperator import Teleoperator
from crowdteleop.errors import ConfigError, UnknownRobotError
from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.tasks import TASK_FILES_VARIABLE, catalogue
from tests.fixtures.motion import arm_motion

ODD_TASKS = """
tasks:
  - {name: wipe, backend: robosuite, env_name: Wipe, instruction: Wipe the table.}
  - {name: wipe-fast, backend: robosuite, env_name: Wipe, instruction: Wipe., fast_path: "on"}
  - {name: no-such-class, backend: robosuite, env_name: NoSuchEnv, instruction: Nothing.}
  - {name: no-such-module, backend: robosuite, env_name: Lift, env_module: no_such_module,
     instruction: Nothing.}
"""


@pytest.fixture
def odd_tasks(tmp_path, monkeypatch):
    path = tmp_path / "odd.yaml"
    path.write_text(ODD_TASKS)
    monkeypatch.setenv(TASK_FILES_VARIABLE, str(path))
    catalogue.cache_clear()
    yield
    catalogue.cache_clear()


def _drive(sim, steps: int = 10):
    sim.reset(seed=0)
    start = sim.robot_state().end_effector.position
    results = [sim.step(arm_motion(sim, index)) for index in range(steps)]
    moved = float(np.linalg.norm(sim.robot_state().end_effector.position - start))
    return results, moved


def test_a_plug_ins_own_environment_runs_on_the_fast_path_with_its_stages(with_task_plugin):
    sim = make_simulation(SimConfig(task="high-lift", robot="Panda"))
    try:
        results, moved = _drive(sim)
        assert sim.fast_path and sim.fast_path_obstacles == []
        assert "crowdteleop_example_tasks.envs" in sys.modules  # its class, imported to build
        assert moved > 0.01
        assert results[-1].progress.message == "Reach for the cube and grasp it."
        assert (results[-1].progress.completed, results[-1].progress.total) == (0, 2)
        assert not results[-1].success
        assert "cube" in sim.object_poses()
    finally:
        sim.close()


def test_a_robot_the_task_does_not_take_is_refused(with_task_plugin):
    with pytest.raises(UnknownRobotError, match=r"does not fit task 'high-lift'.*Panda"):
        make_simulation(SimConfig(task="high-lift", robot="Jaco"))


def test_a_success_function_that_raises_counts_and_the_session_goes_on(with_task_plugin, caplog):
    sim = make_simulation(SimConfig(task="broken-success", robot="Panda"))
    try:
        results, moved = _drive(sim, steps=5)
        assert moved > 0.005 and not any(result.success for result in results)
        assert sim.judge.errors == 5
        assert sum("broken on purpose" in record.message for record in caplog.records) == 1
    finally:
        sim.close()


def test_a_task_running_its_own_step_code_falls_back_to_robosuites_step(odd_tasks, caplog):
    sim = make_simulation(SimConfig(task="wipe", robot="Panda"))
    try:
        _, moved = _drive(sim, steps=5)
        assert not sim.fast_path and "_post_action" in sim.fast_path_obstacles[0]
        assert moved > 0.005
        assert any("robosuite's own path" in record.message for record in caplog.records)
    finally:
        sim.close()


def test_asking_for_the_fast_path_where_it_cannot_serve_is_refused(odd_tasks):
    with pytest.raises(ConfigError, match=r"asks for the fast path.*_post_action"):
        make_simulation(SimConfig(task="wipe-fast", robot="Panda"))


@pytest.mark.parametrize(
    ("task", "message"),
    [
        ("no-such-class", "robosuite could not build 'NoSuchEnv' with robot 'Panda'"),
        ("no-such-module", "cannot import env_module 'no_such_module'"),
    ],
)
def test_an_environment_that_cannot_be_built_is_a_clear_error(odd_tasks, task, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        make_simulation(SimConfig(task=task, robot="Panda"))


class Watch:
    """What a worker would see over an episode: each new stage line, every object touched."""

    def __init__(self) -> None:
        self.seen: list[str] = []
        self.touches: set[str] = set()

    def step(self, step) -> None:
        if not self.seen or self.seen[-1] != step.result.progress.message:
            self.seen.append(step.result.progress.message)
        self.touches.update(contact.object for contact in step.result.contacts)


@pytest.mark.parametrize(
    ("task", "robot", "messages", "touched"),
    [
        (
            "stack",
            "Panda",
            [
                "Reach for the red cube and grasp it.",
                "Red cube grasped: put it on the green cube.",
                "Task done: well done!",
            ],
            "cubeA",
        ),
        (
            "high-lift",
            "IIWA",
            [
                "Reach for the cube and grasp it.",
                "Cube grasped: lift it 10 cm.",
                "Task done: well done!",
            ],
            "cube",
        ),
    ],
)
def test_a_worker_sees_a_new_tasks_stages_success_and_contacts(
    with_task_plugin, task, robot, messages, touched
):
    """What the teleop page shows (the stage line is `progress.message`) and what drives the
    phone's haptics (contacts with the task's objects), for a new built-in and a plug-in task."""
    control = ControlConfig(controller="osc")
    sim = make_simulation(SimConfig(task=task, robot=robot, action_mode=control.action_mode))
    watch = Watch()
    try:
        teleop = Teleoperator(sim, control)
        operator = ScriptedOperator(sim, control.mapping, seed=1)
        result = run_episode(teleop, operator, seed=0, time_limit_s=45.0, on_step=watch.step)
    finally:
        sim.close()
    assert result.success
    assert [m for m in watch.seen if m in messages] == messages, watch.seen
    assert touched in watch.touches


def test_a_plug_ins_own_mjcf_objects_run_on_the_plain_mujoco_backend(with_task_plugin):
    """A package's MJCF objects beside the platform's arm and table, judged by its functions of
    the MuJoCo model and data, with its stages on the worker's line, done by a bot."""
    control = ControlConfig(controller="ik-velocity")
    sim = make_simulation(SimConfig(task="block-lift"))
    watch = Watch()
    try:
        assert {"block", "landing", "table"} <= set(sim.object_poses())
        assert sim.observations()["object"].shape == (20,)  # two objects: 3 + 4 + 3 each
        teleop = Teleoperator(sim, control)
        operator = ScriptedOperator(sim, control.mapping, seed=1)
        result = run_episode(teleop, operator, seed=0, time_limit_s=30.0, on_step=watch.step)
    finally:
        sim.close()
    assert result.success
    wanted = ["Grasp the blue block.", "Lift it 5 cm.", "Task done: well done!"]
    assert [m for m in watch.seen if m in wanted] == wanted, watch.seen
    assert "block" in watch.touches


BAD_SCENES = """
tasks:
  - {name: no-file, backend: mujoco, env_name: x, scene: /nowhere/objects.xml,
     instruction: i, success: "math:isnan"}
  - {name: not-mjcf, backend: mujoco, env_name: x, scene: "crowdteleop:tasks/builtin.py",
     instruction: i, success: "math:isnan"}
"""


@pytest.mark.parametrize(
    ("task", "message"),
    [("no-file", "cannot read its scene '/nowhere/objects.xml'"), ("not-mjcf", "is not MJCF")],
)
def test_a_scene_that_cannot_be_read_is_a_clear_error(tmp_path, monkeypatch, task, message):
    path = tmp_path / "scenes.yaml"
    path.write_text(BAD_SCENES)
    monkeypatch.setenv(TASK_FILES_VARIABLE, str(path))
    catalogue.cache_clear()
    try:
        with pytest.raises(ConfigError, match=re.escape(message)):
            make_simulation(SimConfig(task=task))
    finally:
        catalogue.cache_clear()
