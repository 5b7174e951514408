"""Any task, any robot (issue 31): tasks new to the catalogue and a plug-in package's own task,
on arms besides the default, go through the whole platform as a worker's would: join through a
real coordinator, a bot drives, the teleop server records, `crowdteleop dataset build`, and
robosuite's own playback reads every state back exactly."""

from __future__ import annotations

import asyncio
import json
import os
import subprocess
import sys

import h5py
import pytest

from crowdteleop.crowd.worker import CrowdSettings, run_crowd
from crowdteleop.dataset.robosuite_replay import play_states_in_robosuite
from tests.fixtures.coord import ADMIN, coord_server

pytestmark = [pytest.mark.slow, pytest.mark.exclusive]  # several robots and bots at once

# (task, robot, robosuite's environment class): the campaign hands session i the i-th pair.
# The scripted plans are tuned on Panda with osc; the plug-in's high-lift takes IIWA.
SESSIONS = [
    ("stack", "Panda", "Stack"),
    ("pick-place-milk", "Panda", "PickPlaceMilk"),
    ("pick-place-bread", "Panda", "PickPlaceBread"),
    ("nut-assembly-square", "Panda", "NutAssemblySquare"),
    ("high-lift", "IIWA", "HighLift"),  # tests/fixtures/task_plugin, installed by pip
]
CAMPAIGN = {
    "name": "catalogue",
    "tasks": [task for task, _, _ in SESSIONS],
    "robots": [robot for _, robot, _ in SESSIONS],
    "controllers": ["osc"],
    "demos_required": 1,
    "time_limit_s": 600,
}


def with_path(site) -> dict[str, str]:
    """This environment with the plug-in's folder on PYTHONPATH, as a user installs it."""
    paths = [str(site), os.environ.get("PYTHONPATH", "")]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in paths if p)}


def test_new_tasks_and_a_plug_ins_task_on_other_arms_go_from_join_to_robosuite_playback(
    tmp_path, with_task_plugin
):
    env = with_path(with_task_plugin)
    with coord_server(tmp_path, capacity=3, campaigns=[CAMPAIGN], env=env) as coord:
        # a bot whose plan misses tries again in its session, until its demonstration is done
        settings = CrowdSettings(coord.url, ADMIN, campaign="catalogue", session_timeout_s=240)
        reports = asyncio.run(asyncio.wait_for(run_crowd(settings, len(SESSIONS)), 400))

    for report in reports:
        assert report.error is None, f"{report.name} ({report.task}): {report.error}"
        assert report.completion_code, f"{report.name} ({report.task}) got no code"
        assert report.outcomes.count("success") >= 1
    assert sorted(report.task for report in reports) == sorted(task for task, _, _ in SESSIONS)

    # `dataset build` as a user runs it, in a process that sees the plug-in only by its path
    for task, robot, env_name in SESSIONS:
        dataset = tmp_path / f"{task}.hdf5"
        command = [sys.executable, "-m", "crowdteleop", "dataset", "build", str(coord.data_dir)]
        command += ["--task", task, "--output", str(dataset)]
        built = subprocess.run(command, env=env, capture_output=True, text=True, timeout=120)
        assert built.returncode == 0, built.stdout + built.stderr

        with h5py.File(dataset, "r") as file:
            env_info = json.loads(file["data"].attrs["env_info"])
            demos = sorted(file["data"])
        assert env_info["env_name"] == env_name and env_info["robots"] in (robot, [robot])
        assert demos, f"{task}: no demonstration in the dataset"
        # robosuite's own playback in this process, which never imported the plug-in's code
        for demo in demos:
            playback = play_states_in_robosuite(str(dataset), demo)
            assert playback.max_state_error == 0.0, f"{task} {demo}"
            assert playback.success_at_end, f"{task} {demo}"
