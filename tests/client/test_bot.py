"""The scripted bot (crowdteleop.client.bot), fed the server's messages without a network."""

from __future__ import annotations

import subprocess
import sys
from typing import Any


def _recording_client() -> tuple[Any, list[dict]]:
    """A bot's client that keeps what it sends instead of sending it, its hello received."""
    from crowdteleop.client.connection import TeleopClient
    from crowdteleop.teleop.protocol import Hello

    client = TeleopClient("http://127.0.0.1:9", "worker-token", role="admin", admin_token="x")
    sent: list[dict] = []
    client.send_raw = lambda channel, message: sent.append(message) or True  # type: ignore[method-assign]
    client.state.hello = Hello(
        session_id="s", peer_id="p", role="admin", task="lift", instruction="", fps=20.0,
        width=320, height=240, controlling_device="bot",
    )  # fmt: skip
    return client, sent


def test_the_bot_presses_the_clutch_again_only_once_the_server_applied_its_release():
    """After a reset the server must see the bot let go before the next press: it applies
    only the latest pose of each step, and poses of the last episode may still be arriving
    (pressed). A press that follows the release too soon leaves the server anchored on a
    stale pose, and the bot steering an arm that is not where it thinks (it stalls)."""
    from crowdteleop.client.bot import Bot
    from crowdteleop.sim import SimConfig, make_simulation
    from crowdteleop.teleop.protocol import PrivilegedState
    from crowdteleop.teleop.session import _privileged

    sim = make_simulation(SimConfig(task="lift"))
    try:
        sim.reset(0)
        scene = _privileged(sim, sim.robot_state().end_effector)
    finally:
        sim.close()
    client, sent = _recording_client()
    Bot(client, seed=0)  # drives through client.on_privileged, as messages arrive

    def server_step(step: int, applied_seq: int) -> dict:
        client.on_privileged(PrivilegedState(step=step, scene=1, command_seq=applied_seq, **scene))
        return sent[-1]

    release = server_step(0, applied_seq=0)  # a new scene: let go
    assert release["engaged"] is False
    for step in (1, 2):  # the server still applies older (pressed) poses: keep letting go
        assert server_step(step, applied_seq=release["seq"] - 1)["engaged"] is False
    assert server_step(3, applied_seq=release["seq"])["engaged"] is True  # release applied


def test_the_bot_skips_a_practice_round_once_and_leaves_the_arm_alone_meanwhile():
    """Bots skip the practice round as a worker may (one message): their episodes time the
    task, and they take the very path a worker's page takes (no server setting of their own)."""
    from crowdteleop.client.bot import Bot
    from crowdteleop.teleop.protocol import PrivilegedState, TaskStatus

    client, sent = _recording_client()
    Bot(client, seed=0)
    scene = {"end_effector": (0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), "objects": {}}

    def status(practice: str) -> TaskStatus:
        return TaskStatus(
            episode=0, state="ready", elapsed_s=0, time_limit_s=60, success=False, stage="",
            message="", completed=0, total=0, controlling_device=None, successes=0,
            end_effector=(0.0, 0.0, 1.0), practice=practice, practice_left_s=20.0,
        )  # fmt: skip

    client.state.status = status("running")
    for step in range(3):
        client.on_privileged(PrivilegedState(step=step, scene=1, command_seq=0, **scene))
    assert sent == [{"type": "skip_practice"}]
    client.state.status = status("done")
    client.on_privileged(PrivilegedState(step=3, scene=2, command_seq=0, **scene))
    assert sent[-1]["type"] == "pose", "the round is over: the bot starts its episode"


def test_a_bot_through_a_practice_round_records_episode_one_only(tmp_path):
    import asyncio

    from crowdteleop.client.bot import Bot
    from crowdteleop.client.connection import TeleopClient
    from tests.fixtures.teleop_process import ADMIN_TOKEN, TOKEN, run, teleop_server

    with teleop_server(tmp_path, practice_s=20) as server:

        async def scenario():
            client = TeleopClient(server.url, TOKEN, role="admin", admin_token=ADMIN_TOKEN)
            bot = Bot(client, seed=0)
            await client.connect()
            try:
                result = await bot.run(episodes=1, timeout_s=120)
                await asyncio.sleep(1.5)  # the episode is stored off the control loop
                return result, list(client.state.episodes), client.state.status
            finally:
                await client.close()

        result, episodes, status = run(scenario())
        stored = sorted(server.record_dir.rglob("*.hdf5"))

    assert result.episodes == ["success"]
    assert [episode.episode for episode in episodes] == [1]
    assert (status.practice, status.practice_reached) == ("done", False)
    assert len(stored) == 1, "the practice round left no recording"


def test_the_bot_loads_no_simulator():
    """A bot machine runs many network clients: it reads poses (`sim.types`, plain data) and
    never steps a robot, so it needs neither MuJoCo nor robosuite. (scipy it does load: the
    scripted operator turns the virtual phone with scipy's rotations.)"""
    probe = (
        "import sys, crowdteleop.client.bot; "
        "print(','.join(m for m in ('mujoco', 'robosuite', 'mink') if m in sys.modules))"
    )
    loaded = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert loaded == ""
