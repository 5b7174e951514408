"""A teleop server stopped mid-episode: `kill -9` loses at most the last flush interval;
SIGTERM (what process managers send) stores the episode before the process exits."""

from __future__ import annotations

import asyncio
import signal

import numpy as np

from crowdteleop.client.bot import Bot
from crowdteleop.client.connection import TeleopClient
from crowdteleop.recording.episode_file import read_episode
from crowdteleop.recording.wal_reader import read_partial
from crowdteleop.sim import SimConfig, make_simulation
from tests.fixtures.teleop_process import ADMIN_TOKEN, TOKEN, run, teleop_server

FLUSH_S = 0.2
CONTROL_DT = 0.05


async def bot_in_an_episode(url: str, elapsed_s: float) -> TeleopClient:
    """A scripted worker driving the session, once its episode has run ``elapsed_s``."""
    client = TeleopClient(url, TOKEN, role="admin", admin_token=ADMIN_TOKEN)
    Bot(client, seed=1)
    await client.connect()
    await client.wait_for(
        lambda s: s.status is not None and s.status.elapsed_s >= elapsed_s, timeout=60
    )
    return client


def test_kill_9_mid_episode_keeps_every_step_up_to_the_last_flush(tmp_path):
    recording = {"flush_interval_s": FLUSH_S}
    with teleop_server(tmp_path, recording=recording) as server:

        async def drive_then_kill():
            client = await bot_in_an_episode(server.url, elapsed_s=1.5)
            seen_steps = round(client.state.status.elapsed_s / CONTROL_DT)
            server.kill9()
            await client.close()
            return seen_steps

        seen_steps = run(drive_then_kill())
        logs = sorted((server.record_dir / "incoming").glob("*.wal"))
        assert len(logs) == 1, "the episode's write-ahead log outlives the process"
        partial = read_partial(logs[0])

    # Every step the worker saw, minus at most one flush interval (and the step in flight).
    assert partial.steps >= seen_steps - (FLUSH_S / CONTROL_DT + 2)
    assert partial.steps <= seen_steps + 3
    sim = make_simulation(SimConfig(**partial.metadata["sim_config"]))
    try:
        sim.set_state(partial.states[0])
        # the finger command robosuite's gripper ramps is state beside [time, qpos, qvel]
        sim.set_controller_state(np.array(partial.metadata["controller_state_at_start"]))
        for state, action in zip(partial.states[1:], partial.actions[:-1], strict=True):
            sim.step(action)
            np.testing.assert_array_equal(sim.get_state(), state)
    finally:
        sim.close()

    # The next server on the same directory files it as a crashed episode.
    with teleop_server(tmp_path) as restarted:
        crashed = sorted((restarted.record_dir / "other").glob("*.hdf5"))
    assert len(crashed) == 1
    episode = read_episode(crashed[0])
    assert episode.outcome == "crash" and episode.steps == partial.steps


def test_sigterm_mid_episode_stores_the_episode_and_exits(tmp_path):
    with teleop_server(tmp_path) as server:

        async def drive_then_terminate():
            client = await bot_in_an_episode(server.url, elapsed_s=1.0)
            server.process.send_signal(signal.SIGTERM)
            exit_code = await asyncio.to_thread(server.process.wait, 30)
            await client.close()
            return exit_code

        exit_code = run(drive_then_terminate())
        stored = sorted((server.record_dir / "other").glob("*.hdf5"))
        logs = sorted((server.record_dir / "incoming").glob("*.wal"))

    assert exit_code == 0
    assert logs == [], "the episode was finalized, not left to crash recovery"
    assert len(stored) == 1
    episode = read_episode(stored[0])
    assert episode.outcome == "disconnect" and episode.steps >= 20


def test_a_server_whose_parent_blocked_sigint_still_stops_on_it(tmp_path):
    """A Ray actor starts its teleop server from a thread with SIGINT blocked, and a child
    inherits the mask: the launcher's SIGINT (store the episode, then exit) must still work."""
    with teleop_server(tmp_path, blocked={signal.SIGINT}) as server:
        server.process.send_signal(signal.SIGINT)
        exit_code = server.process.wait(15)
    assert exit_code == 0, server.log()[-2000:]
