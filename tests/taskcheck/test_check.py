"""`crowdteleop tasks check NAME` measures a task against plain robosuite and says whether the
fast path is faithful there, as a researcher registering a task would run it."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from crowdteleop.cli import app
from crowdteleop.taskcheck.check import DRIFT_P95_LIMIT_M, MAD_LIMIT
from crowdteleop.tasks import TASK_FILES_VARIABLE, catalogue

runner = CliRunner()


@pytest.mark.slow
def test_a_new_built_in_task_is_checked_faithful_with_its_figures(tmp_path):
    figures = tmp_path / "stack.json"
    result = runner.invoke(
        app,
        ["tasks", "check", "stack", "--json", str(figures)],  # a whole scripted episode
    )
    assert result.exit_code == 0, result.output
    assert "the fast path is faithful here" in result.output
    measured = json.loads(figures.read_text())
    assert measured["fast_path"] and measured["problems"] == []
    assert measured["step_ratio"] > 1.5, "the fast path should step faster than robosuite"
    assert measured["picture_mad"] <= MAD_LIMIT and measured["drift_p95_m"] <= DRIFT_P95_LIMIT_M


@pytest.mark.slow
def test_a_task_on_robosuites_own_path_says_why(tmp_path, monkeypatch):
    path = tmp_path / "wipe.yaml"
    path.write_text("tasks:\n  - {name: wipe, backend: robosuite, env_name: Wipe, instruction: W}")
    monkeypatch.setenv(TASK_FILES_VARIABLE, str(path))
    catalogue.cache_clear()
    try:
        result = runner.invoke(app, ["tasks", "check", "wipe", "--steps", "10"])
    finally:
        catalogue.cache_clear()
    assert result.exit_code == 0, result.output
    assert "robosuite's own path" in result.output and "_post_action" in result.output
