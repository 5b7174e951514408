"""The task catalogue: built-in tasks, and plug-ins from an installed package's entry point or a
YAML file; a broken plug-in is left out with the reason, never taking the others down."""

from __future__ import annotations

import subprocess
import sys

import pytest

from crowdteleop.errors import ConfigError, UnknownTaskError
from crowdteleop.tasks import (
    TASK_FILES_VARIABLE,
    Stage,
    TaskSpec,
    catalogue,
    get_task,
    load_catalogue,
    task_names,
)

NEW_ROBOSUITE_TASKS = [
    "stack",
    "pick-place-milk",
    "pick-place-bread",
    "pick-place-cereal",
    "nut-assembly-square",
]

STACK_YAML = """
tasks:
  - name: my-stack
    backend: robosuite
    env_name: Stack
    instruction: Put the red cube on the green one.
    time_limit_s: 45
    robots: [Panda]
    stages:
      - name: reach
        instruction: Grasp the red cube.
        done_when: "crowdteleop.sim.robosuite_backend.stages:holds_cube_a"
      - name: stack
        instruction: Now stack it.
        done_when: "crowdteleop.sim.robosuite_backend.stages:stacked"
"""
DECLARE = "tasks:\n  - {{backend: robosuite, env_name: Lift, instruction: i, {}}}"


def test_the_built_in_tasks_include_more_of_robosuites():
    names = task_names()
    assert {"lift", "pick-place-can", "nut-assembly-round", *NEW_ROBOSUITE_TASKS} <= set(names)
    assert len(set(names)) == len(names)
    assert all(get_task(name).source == "built-in" for name in names)


def test_a_yaml_file_declares_a_task_with_stages(tmp_path):
    path = tmp_path / "tasks.yaml"
    path.write_text(STACK_YAML)
    found = load_catalogue({TASK_FILES_VARIABLE: str(path)})
    task = found.get("my-stack")
    assert found.problems == ()
    assert task.env_name == "Stack" and task.robots == ("Panda",) and task.time_limit_s == 45
    assert [stage.name for stage in task.stages] == ["reach", "stack"]
    assert task.source == f"file {path}"


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        (DECLARE.format("name: x1, colour: red"), "colour"),
        (DECLARE.format("name: Bad Name"), "lowercase"),
        (DECLARE.format("name: x2, success: nope"), "not a reference"),
        (DECLARE.format("name: x3, robots: [R2D2]"), "R2D2"),
        (DECLARE.format("name: lift"), "already declared by built-in"),
        ("just text", "top-level 'tasks:' list"),
        ("tasks: [", "while parsing"),
    ],
)
def test_a_broken_task_file_is_left_out_with_its_reason(tmp_path, text, reason):
    path = tmp_path / "tasks.yaml"
    path.write_text(text)
    found = load_catalogue({TASK_FILES_VARIABLE: str(path)})
    assert len(found.problems) == 1 and reason in found.problems[0], found.problems
    assert str(path) in found.problems[0]
    assert found.get("lift").source == "built-in"  # the rest still there


def test_a_missing_task_says_which_plug_ins_were_left_out(tmp_path):
    missing = tmp_path / "nowhere.yaml"
    found = load_catalogue({TASK_FILES_VARIABLE: str(missing)})
    with pytest.raises(UnknownTaskError, match=r"nowhere\.yaml"):
        found.get("my-stack")


def test_a_declaration_in_code_is_checked_when_made():
    with pytest.raises(ConfigError, match="time_limit_s must be > 0"):
        TaskSpec("x", "robosuite", "Lift", "Lift it.", time_limit_s=0)
    with pytest.raises(ConfigError, match="not a reference"):
        TaskSpec("x", "robosuite", "Lift", "Lift it.", stages=(Stage("a", "b", "no-colon"),))


def test_an_installed_packages_entry_point_adds_its_tasks(with_task_plugin):
    task = get_task("high-lift")
    assert task.env_module == "crowdteleop_example_tasks.envs"
    assert task.source == "entry point 'example' (crowdteleop_example_tasks:TASKS)"
    assert catalogue().problems == ()


def test_crowdteleop_tasks_lists_a_plug_in_in_a_new_process(task_plugin_site, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("tasks: {}")
    listing = subprocess.run(
        [sys.executable, "-m", "crowdteleop", "tasks"],
        env={
            "PYTHONPATH": str(task_plugin_site),
            TASK_FILES_VARIABLE: str(bad),
            "COLUMNS": "200",
            "PATH": "/usr/bin:/bin",
        },
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "high-lift" in listing and "entry point 'example'" in listing
    assert "stack" in listing and "left out" in listing and "bad.yaml" in listing


def test_reading_the_catalogue_imports_no_simulator_and_no_plug_in_code(task_plugin_site):
    """The coordinator reads the catalogue: a plug-in's environment stays unimported there."""
    probe = (
        "import sys; from crowdteleop.tasks import get_task; get_task('high-lift'); "
        "print(sorted(m for m in ('crowdteleop_example_tasks.envs', 'robosuite', 'mujoco') "
        "if m in sys.modules))"
    )
    loaded = subprocess.run(
        [sys.executable, "-c", probe],
        env={"PYTHONPATH": str(task_plugin_site), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert loaded == "[]"


@pytest.mark.parametrize(
    ("fields", "reason"),
    [
        ("backend: mujoco, env_name: mine", "names its objects' MJCF file (scene)"),
        ("backend: mujoco, env_name: mine, scene: s.xml", "says when it is done (success)"),
        ("backend: robosuite, env_name: Lift, scene: s.xml", "set backend: mujoco"),
    ],
)
def test_a_plain_mujoco_task_names_its_scene_and_its_success(tmp_path, fields, reason):
    path = tmp_path / "tasks.yaml"
    path.write_text(f"tasks:\n  - {{name: mine, instruction: i, {fields}}}")
    found = load_catalogue({TASK_FILES_VARIABLE: str(path)})
    assert len(found.problems) == 1 and reason in found.problems[0], found.problems
