"""`crowdteleop node`: a machine checked and joined to the Ray cluster in one command, which
installs nothing and starts nothing when something the node needs is missing (issue 30). The
`ray start` it runs is exercised by the guide's test (tests/coord/test_deploy_guide.py)."""

from __future__ import annotations

import json
import shlex

from typer.testing import CliRunner

from crowdteleop.cli import app

runner = CliRunner(env={"COLUMNS": "300"})  # a table row on one line


def test_check_lists_what_a_node_needs_and_finds_it_here(tmp_path):
    done = runner.invoke(app, ["node", "check", "--ip", "127.0.0.1", "--work-dir", str(tmp_path)])
    assert done.exit_code == 0, done.output
    for name in ("python package ray", "offscreen rendering", "address", "work folder"):
        assert name in done.output
    assert "missing" not in done.output


def test_start_prints_the_ray_command_with_the_nodes_slots_and_address(tmp_path):
    args = ["node", "start", "--ip", "127.0.0.1", "--address", "10.0.0.11:6379"]
    args += ["--slots", "3", "--work-dir", str(tmp_path), "--dry-run"]
    done = runner.invoke(app, args)
    assert done.exit_code == 0, done.output
    line = next(line for line in done.output.splitlines() if line.startswith("$ "))
    command = shlex.split(line[2:])
    assert command[1] == "start" and "--address=10.0.0.11:6379" in command
    assert "--node-ip-address=127.0.0.1" in command
    resources = next(a for a in command if a.startswith("--resources="))
    assert json.loads(resources.split("=", 1)[1]) == {"teleop": 3}


def test_a_head_gets_the_guides_port_and_no_dashboard(tmp_path):
    args = ["node", "start", "--ip", "127.0.0.1", "--work-dir", str(tmp_path), "--dry-run"]
    done = runner.invoke(app, args)
    assert done.exit_code == 0, done.output
    assert "--head --port=6379 --include-dashboard=false" in done.output
    assert "teleop slots:" in done.output, "sized from the machine when not given, and said"


def test_an_address_of_another_machine_is_refused_and_nothing_started(tmp_path):
    args = ["node", "start", "--ip", "203.0.113.9", "--work-dir", str(tmp_path), "--slots", "1"]
    done = runner.invoke(app, args)
    assert done.exit_code == 1
    assert "203.0.113.9 is not an address of this machine" in done.output
    assert "not started" in done.output and "$ " not in done.output
