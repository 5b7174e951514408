"""Stale-input safety, as hosted teleoperation of real robots needs it, through a teleop
server process and a real WebRTC client on loopback:

- a pose that arrives older than the limit (its client clock mapped onto the server's through
  ping / pong) is not applied, is counted, and the worker is told; fresh ones drive again;
- the worker's page reporting its video stalled releases the clutch for every device, the
  status says so, and driving resumes only after the device lets go and presses again."""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest

from crowdteleop.client.connection import TeleopClient
from tests.fixtures.teleop_process import TOKEN, run, teleop_server

# runs alone under xdist: ages of poses and stalls, in milliseconds
pytestmark = pytest.mark.exclusive

IDENTITY = (0.0, 0.0, 0.0, 1.0)


def send_pose_sent_ago(client: TeleopClient, position, engaged: bool, age_ms: float) -> None:
    """A pose stamped ``age_ms`` ago: what arrives after that long in a network queue."""
    client.send_raw(
        "control",
        {
            "type": "pose",
            "seq": client._next_seq(),
            "client_time_ms": time.time() * 1e3 - age_ms,
            "device": client.device,
            "position": [float(x) for x in position],
            "quaternion": list(IDENTITY),
            "engaged": engaged,
            "gripper": False,
        },
    )


async def drive(client: TeleopClient, offset, age_ms: float = 0.0, steps: int = 25) -> None:
    """Hold the clutch and carry the device by ``offset``, every pose ``age_ms`` old."""
    for i in range(steps + 1):
        position = np.asarray(offset) * min(1.0, i / (steps * 0.6))
        send_pose_sent_ago(client, position, True, age_ms)
        await asyncio.sleep(0.05)
    await asyncio.sleep(0.6)


def hand(client: TeleopClient) -> np.ndarray:
    return np.array(client.state.status.end_effector)


async def connected(server) -> TeleopClient:
    client = TeleopClient(server.url, TOKEN, device="keyboard")
    await client.connect()
    # the first server pings (one a second) tell the server our clock
    await client.wait_for(lambda s: s.status is not None and s.telemetry is not None, 30)
    await asyncio.sleep(2.5)
    return client


def test_late_poses_are_not_applied_and_the_worker_is_told(tmp_path):
    with teleop_server(tmp_path) as server:

        async def scenario():
            client = await connected(server)
            start = hand(client)
            await drive(client, [0.0, 0.10, 0.0], age_ms=2000.0)
            after_late = hand(client)
            telemetry = await server.telemetry()
            told = [e for e in client.state.errors if e.code == "stale_input"]
            send_pose_sent_ago(client, [0.0, 0.0, 0.0], False, 0.0)  # let go, then drive fresh
            await asyncio.sleep(0.3)
            await drive(client, [0.0, 0.10, 0.0])
            after_fresh = hand(client)
            await client.close()
            return start, after_late, after_fresh, telemetry, told

        start, after_late, after_fresh, telemetry, told = run(scenario())

    assert np.linalg.norm(after_late - start) < 0.005, "two-second-old poses moved the arm"
    assert telemetry["errors"]["stale_input"] >= 20, telemetry["errors"]
    assert told, "the worker was told"
    assert "not applied" in told[0].message
    assert len(told) <= 2, "told every few seconds, not once per pose"
    assert after_fresh[1] - after_late[1] > 0.07, "fresh poses drive again"


def test_a_video_stall_releases_the_clutch_until_a_fresh_press(tmp_path):
    with teleop_server(tmp_path) as server:

        async def scenario():
            client = await connected(server)
            start = hand(client)
            client.send_raw("events", {"type": "video", "stalled": True, "gap_ms": 1500.0})
            await client.wait_for(lambda s: s.status.video_stalled, 5)
            await drive(client, [0.0, 0.10, 0.0])
            during_stall = hand(client)
            client.send_raw("events", {"type": "video", "stalled": False, "gap_ms": 1800.0})
            await client.wait_for(lambda s: not s.status.video_stalled, 5)
            await drive(client, [0.0, 0.10, 0.0])  # the button still held from before
            held_through = hand(client)
            send_pose_sent_ago(client, [0.0, 0.0, 0.0], False, 0.0)  # let go
            await asyncio.sleep(0.3)
            await drive(client, [0.0, 0.10, 0.0])  # and press again
            pressed_again = hand(client)
            telemetry = await server.telemetry()
            await client.close()
            return start, during_stall, held_through, pressed_again, telemetry

        start, during_stall, held_through, pressed_again, telemetry = run(scenario())

    assert np.linalg.norm(during_stall - start) < 0.005, "the arm moved while the video was off"
    assert np.linalg.norm(held_through - start) < 0.005, "an old press drove after the stall"
    assert pressed_again[1] - held_through[1] > 0.07, "a fresh press drives"
    assert telemetry["video_stalls"] == 1


def test_only_a_stall_of_every_worker_page_counts(tmp_path):
    """A second tab left open in the background stops showing video; the one the worker
    looks at still does, so nothing is stalled until both say so."""
    with teleop_server(tmp_path) as server:

        async def scenario():
            seen = []
            front, back = await connected(server), await connected(server)
            back.send_raw("events", {"type": "video", "stalled": True, "gap_ms": 1500.0})
            await asyncio.sleep(1.0)
            seen.append(front.state.status.video_stalled)
            front.send_raw("events", {"type": "video", "stalled": True, "gap_ms": 1500.0})
            await front.wait_for(lambda s: s.status.video_stalled, 5)
            seen.append(True)
            front.send_raw("events", {"type": "video", "stalled": False, "gap_ms": 1600.0})
            await front.wait_for(lambda s: not s.status.video_stalled, 5)
            seen.append(False)
            await front.close()  # the page that saw video leaves: only the stalled one is left
            await back.wait_for(lambda s: s.status.video_stalled, 5)
            seen.append(True)
            # the worker opens the link again: the new tab shows video, the arm is free
            again = await connected(server)
            await again.wait_for(lambda s: s.status is not None and not s.status.video_stalled, 5)
            seen.append(False)
            await again.close()
            await back.close()
            return seen

        assert run(scenario()) == [False, True, False, True, False]
