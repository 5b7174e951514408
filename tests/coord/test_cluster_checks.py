"""A coordinator on a cluster of several machines refuses, at start and with what to set,
settings that would lose the campaign's demonstrations (issue 30): a report address on its
loopback, and episodes kept on each node's own disk."""

from __future__ import annotations

from crowdteleop.coord.fleet.cluster_checks import TeleopNode, cluster_problems

HERE = {"127.0.0.1", "::1", "localhost", "10.0.0.11"}  # the coordinator's machine
TWO_MACHINES = [TeleopNode("10.0.0.11", 8), TeleopNode("10.0.0.12", 8)]


def test_a_loopback_report_address_is_refused_when_a_node_is_another_machine():
    problems = cluster_problems(TWO_MACHINES, "http://127.0.0.1:8000/internal/episodes", True, HERE)
    assert len(problems) == 1
    assert "10.0.0.12" in problems[0] and "10.0.0.11" not in problems[0].split("would")[0]
    assert "`internal_url`" in problems[0] and "docs/deploy.md" in problems[0]


def test_a_report_address_every_node_reaches_is_accepted():
    for url in ("https://teleop.example.org/internal/episodes", "http://10.0.0.11:8000/x"):
        assert cluster_problems(TWO_MACHINES, url, True, HERE) == []


def test_loopback_serves_a_cluster_whose_nodes_are_all_this_machine():
    nodes = [TeleopNode("127.0.0.1", 1), TeleopNode("127.0.0.1", 1), TeleopNode("10.0.0.11", 2)]
    for url in ("http://127.0.0.1:8000/i", "http://localhost:8000/i", "http://[::1]:8000/i"):
        assert cluster_problems(nodes, url, True, HERE) == []


def test_local_episodes_on_several_machines_are_refused_unless_the_folder_is_shared():
    url = "https://teleop.example.org/internal/episodes"
    problems = cluster_problems(TWO_MACHINES, url, False, HERE)
    assert len(problems) == 1 and "S3-compatible" in problems[0]
    assert "shared_storage: true" in problems[0]
    assert cluster_problems(TWO_MACHINES, url, True, HERE) == []  # S3, or a shared mount
    one = [TeleopNode("10.0.0.11", 8)]
    assert cluster_problems(one, url, False, HERE) == [], "one machine's disk is the coordinator's"


def test_both_problems_are_said_together():
    problems = cluster_problems(TWO_MACHINES, "http://localhost:8000/i", False, HERE)
    assert len(problems) == 2
