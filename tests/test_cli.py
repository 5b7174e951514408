"""`crowdteleop demo` (what `make run` does for now) films a scripted episode to an MP4."""

from __future__ import annotations

import subprocess
import sys

import av
import numpy as np


def crowdteleop(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "crowdteleop", *args], capture_output=True, text=True, timeout=600
    )


def test_demo_writes_a_playable_mp4_of_a_successful_episode(tmp_path):
    output = tmp_path / "lift.mp4"
    run = crowdteleop("demo", "--task", "lift", "--seed", "3", "--output", str(output))
    assert run.returncode == 0, run.stdout + run.stderr
    assert "success" in run.stdout
    with av.open(str(output)) as container:
        frames = [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]
    assert len(frames) > 20 and frames[0].shape == (240, 320, 3)
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 1.0


def test_demo_rejects_an_unknown_task_with_a_readable_message(tmp_path):
    run = crowdteleop("demo", "--task", "juggle", "--output", str(tmp_path / "x.mp4"))
    assert run.returncode == 2
    assert "unknown task 'juggle'" in run.stdout and "Traceback" not in run.stderr


def test_tasks_lists_the_papers_tasks():
    run = crowdteleop("tasks")
    assert run.returncode == 0
    for name in ("lift", "pick-place-can", "nut-assembly-round"):
        assert name in run.stdout


def test_the_bot_command_completes_an_episode_through_a_teleop_server(tmp_path):
    import subprocess
    import sys

    from tests.fixtures.teleop_process import ADMIN_TOKEN, TOKEN, teleop_server

    with teleop_server(tmp_path) as server:
        result = subprocess.run(
            [
                sys.executable,
                "-m",
                "crowdteleop",
                "bot",
                "--url",
                server.url,
                "--token",
                TOKEN,
                "--admin-token",
                ADMIN_TOKEN,
                "--episodes",
                "1",
                "--timeout",
                "120",
            ],
            capture_output=True,
            text=True,
            timeout=180,
        )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1/1 episodes succeeded (success)" in result.stdout


def test_the_bot_needs_the_admin_token():
    import subprocess
    import sys

    result = subprocess.run(
        [sys.executable, "-m", "crowdteleop", "bot", "--url", "http://127.0.0.1:9"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2 and "--admin-token" in result.stdout


def test_the_bot_offers_synthetic_workers_of_known_skill():
    import os

    run = subprocess.run(
        [sys.executable, "-m", "crowdteleop", "bot", "--help"],
        capture_output=True,
        text=True,
        timeout=60,
        env={**os.environ, "COLUMNS": "200"},
    )
    assert run.returncode == 0
    assert "--skill" in run.stdout and "expert|intermediate|novice" in run.stdout


def test_an_unknown_skill_is_a_clear_error():
    run = crowdteleop("bot", "--admin-token", "admin-token", "--skill", "guru")
    output = " ".join((run.stdout + run.stderr).split())
    assert run.returncode == 2 and "'guru' is not one of" in output and "novice" in output
    crowd = crowdteleop(
        "bot", "--admin-token", "a", "--coordinator", "http://127.0.0.1:9", "--skills", "novice,x"
    )
    assert crowd.returncode == 2 and "unknown skill(s) 'x'" in crowd.stdout
    assert "Traceback" not in run.stderr + crowd.stderr


def test_an_unknown_fault_is_a_clear_error_and_faults_are_for_a_crowd():
    crowd = crowdteleop(
        "bot", "--admin-token", "a", "--coordinator", "http://127.0.0.1:9", "--faults", "idle,x"
    )
    assert crowd.returncode == 2 and "unknown fault(s) 'x'" in crowd.stdout
    assert "idle, detour, drop, press" in crowd.stdout
    alone = crowdteleop("bot", "--admin-token", "a", "--faults", "idle")
    assert alone.returncode == 2 and "--faults are for a crowd" in alone.stdout


def test_a_bad_option_is_named_in_the_error():
    run = crowdteleop("teleop-server", "--task", "lift", "--token", "short", "--port", "0")
    assert run.returncode == 2
    output = " ".join((run.stdout + run.stderr).split())  # rich wraps long lines
    assert "token: String should have at least 8 characters" in output
    assert "Traceback" not in output


# What `crowdteleop serve` runs: the command line resolving `serve`, then the app it serves.
SERVE_PATH = """
import sys
from crowdteleop.cli import app
try:
    app(["serve", "--help"], prog_name="crowdteleop")
except SystemExit:
    pass
import crowdteleop.coord.app
heavy = ("scipy", "mujoco", "robosuite", "h5py", "torch")
print("LOADED:" + ",".join(name for name in heavy if name in sys.modules))
"""


def test_serve_loads_neither_scipy_nor_the_simulator():
    """The dataset and learn commands are listed without importing them, so a coordinator
    on a small machine in front of a cluster starts without scipy, MuJoCo or torch."""
    run = subprocess.run(
        [sys.executable, "-c", SERVE_PATH], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stderr
    assert "crowdteleop serve" in run.stdout, "the serve command was reached"
    [loaded] = [line for line in run.stdout.splitlines() if line.startswith("LOADED:")]
    assert loaded == "LOADED:", f"`crowdteleop serve` imported {loaded.removeprefix('LOADED:')}"


def test_the_deferred_command_groups_load_when_run_and_say_what_they_do():
    import importlib

    import typer.main
    from typer.testing import CliRunner

    from crowdteleop.cli import DEFERRED_GROUPS, app

    for name, (target, help_text) in DEFERRED_GROUPS.items():
        module, _, attribute = target.partition(":")
        group = typer.main.get_group(getattr(importlib.import_module(module), attribute))
        assert group.help == help_text, f"the listing's help of {name} is its own"
        listed = CliRunner().invoke(app, [name, "--help"])
        assert listed.exit_code == 0, listed.output
        assert all(command in listed.output for command in group.commands), listed.output
