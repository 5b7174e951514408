"""A task whose robot cannot be built (a plug-in's class robosuite does not know) fails its own
sessions with a reason in the log; the running coordinator and every other task go on."""

from __future__ import annotations

import os

import pytest

from crowdteleop.tasks import TASK_FILES_VARIABLE
from tests.fixtures.coord import Api, coord_server

pytestmark = pytest.mark.slow

BROKEN = """
tasks:
  - {name: broken-class, backend: robosuite, env_name: NoSuchEnv, instruction: Nothing works.}
"""


def test_a_task_that_cannot_be_built_ends_its_sessions_and_nothing_else(tmp_path):
    tasks = tmp_path / "tasks.yaml"
    tasks.write_text(BROKEN)
    env = {**os.environ, TASK_FILES_VARIABLE: str(tasks)}
    campaign = {"name": "mixed", "tasks": ["broken-class", "lift"], "time_limit_s": 600}
    with coord_server(tmp_path, capacity=1, campaigns=[campaign], env=env) as coord:
        with coord.client() as client:
            api = Api(client)
            first = api.join()["worker_token"]
            broken = api.new_session(first)["session_id"]
            ended = api.wait_state(first, broken, "ended", timeout=120)
            assert ended["ended_reason"] == "error"

            second = api.join()["worker_token"]
            working = api.new_session(second)["session_id"]
            assert api.wait_state(second, working, "ready", timeout=120)["task"] == "lift"
            assert client.get("/health").status_code == 200
        assert coord.process.poll() is None, "the coordinator kept running"
        # the coordinator's log quotes the server's one-line reason
        assert "robosuite could not build 'NoSuchEnv' with robot 'Sawyer'" in coord.log()
