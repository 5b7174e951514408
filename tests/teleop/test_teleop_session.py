"""A teleop server process and real WebRTC clients on loopback: what a worker experiences."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest

from crowdteleop.client.bot import Bot
from crowdteleop.client.connection import OfferRefusedError, TeleopClient
from crowdteleop.recording.episode_file import read_episode
from crowdteleop.sim import SimConfig, make_simulation
from tests.fixtures.teleop_process import ADMIN_TOKEN, TOKEN, run, teleop_server

pytestmark = pytest.mark.exclusive  # runs alone under xdist: frame and control rates

IDENTITY = (0.0, 0.0, 0.0, 1.0)


async def _drive(client: TeleopClient, offset: np.ndarray, steps: int = 30) -> None:
    """Hold the clutch and move the device from the origin by `offset`, as a hand would."""
    for i in range(steps + 1):
        client.send_pose(offset * min(1.0, i / (steps * 0.6)), IDENTITY, True, False)
        await asyncio.sleep(0.05)


def test_frames_and_end_effector_follow_the_device(tmp_path):
    with teleop_server(tmp_path) as server:

        async def scenario():
            client = TeleopClient(server.url, TOKEN, device="keyboard")
            await client.connect()
            await client.wait_for(lambda s: s.frames_received >= 5 and s.status, 30)
            before_frame = client.state.latest_frame.copy()
            before = np.array(client.state.status.end_effector)
            await _drive(client, np.array([0.0, 0.10, 0.05]))
            await asyncio.sleep(1.0)
            after = np.array(client.state.status.end_effector)
            after_frame = client.state.latest_frame.copy()
            fps = client.state.fps()
            latency = list(client.latency.samples_ms)
            await client.close()
            return before, after, before_frame, after_frame, fps, latency

        before, after, before_frame, after_frame, fps, latency = run(scenario())

    assert before_frame.shape == (240, 320, 3)
    moved = after - before
    assert moved[1] == pytest.approx(0.10, abs=0.015)
    assert moved[2] == pytest.approx(0.05, abs=0.015)
    assert np.abs(after_frame.astype(int) - before_frame.astype(int)).mean() > 1.0
    assert fps > 15
    assert len(latency) > 10 and np.median(latency) < 150


def test_a_bot_completes_lift_and_the_episode_replays_exactly(tmp_path):
    with teleop_server(tmp_path) as server:

        async def scenario():
            bot_client = TeleopClient(server.url, TOKEN, role="admin", admin_token=ADMIN_TOKEN)
            phone = TeleopClient(server.url, TOKEN, role="phone", device="phone")
            bot = Bot(bot_client, seed=0)
            await bot_client.connect()
            await phone.connect()
            result = await bot.run(episodes=1, timeout_s=120)
            await asyncio.sleep(1.5)  # the episode is finalized off the control loop
            telemetry = await server.telemetry()
            haptics = list(phone.state.haptics)
            phone_frames = phone.state.frames_received
            await phone.close()
            await bot_client.close()
            return result, telemetry, haptics, phone_frames

        result, telemetry, haptics, phone_frames = run(scenario())
        stored = sorted((server.record_dir / "success").glob("*.hdf5"))

    assert result.episodes == ["success"]
    assert len(stored) == 1
    assert any(h.object == "cube" for h in haptics), "the phone buzzes when the gripper touches"
    assert phone_frames == 0, "the phone gets no video"
    assert telemetry["loop_hz"] > 15, "the loop runs at its rate (benchmarks/teleop.py measures)"
    # the receiver's own bandwidth estimate (its REMB), which labels the network condition
    assert telemetry.get("receiver_kbps", 0) > 0, telemetry

    episode = read_episode(stored[0])
    assert episode.outcome == "success"
    assert episode.metadata["task"] == "lift"
    assert episode.success[-10:].all()
    labels = episode.labels  # each row's subtask label, read in the sim thread before its step
    assert labels is not None and len(labels.stage) == episode.steps
    assert "reach" in labels.stage and labels.relative_to[labels.stage.index("reach")] == "cube"
    assert set(labels.object_poses) >= {"cube"}
    sim = make_simulation(SimConfig(**episode.metadata["sim_config"]))
    try:
        assert sim.mjcf_xml() == episode.model_xml, "the config rebuilds the recorded model"
        for t in (0, episode.steps - 1):  # the labels describe the row's state
            sim.set_state(episode.states[t])
            hand = sim.robot_state().end_effector
            np.testing.assert_allclose(
                labels.hand_pose[t], [*hand.position, *hand.quaternion], rtol=0, atol=1e-9
            )
            assert labels.stage[t] == sim.progress().stage
        sim.set_state(episode.states[0])
        # the finger command robosuite's gripper ramps is state beside [time, qpos, qvel]
        sim.set_controller_state(np.array(episode.metadata["controller_state_at_start"]))
        for state, action in zip(episode.states[1:], episode.actions[:-1], strict=True):
            sim.step(action)
            np.testing.assert_array_equal(sim.get_state(), state)
        sim.step(episode.actions[-1])
        assert sim.success()
    finally:
        sim.close()


def test_one_device_drives_at_a_time_and_switching_is_explicit(tmp_path):
    with teleop_server(tmp_path) as server:

        async def scenario():
            browser = TeleopClient(server.url, TOKEN, device="keyboard")
            phone = TeleopClient(server.url, TOKEN, role="phone", device="phone")
            await browser.connect()
            await phone.connect()
            browser.send_pose((0, 0, 0), IDENTITY, True, False)
            await browser.wait_for(lambda s: s.status and s.status.controlling_device, 10)
            first = browser.state.status.controlling_device
            phone.send_pose((0, 0, 0), IDENTITY, True, False)
            await phone.wait_for(lambda s: s.errors, 10)
            refused = phone.state.errors[0].code
            phone.take_control()
            await browser.wait_for(
                lambda s: s.status and s.status.controlling_device == "phone", 10
            )
            before = np.array(browser.state.status.end_effector)
            await _drive(phone, np.array([0.08, 0.0, 0.0]))
            await asyncio.sleep(1.0)
            moved = np.array(browser.state.status.end_effector) - before
            await phone.close()
            await browser.close()
            return first, refused, moved

        first, refused, moved = run(scenario())

    assert first == "keyboard"
    assert refused == "not_in_control"
    assert moved[0] == pytest.approx(0.08, abs=0.015)


def test_wrong_tokens_are_refused_with_a_reason(tmp_path):
    with teleop_server(tmp_path) as server:

        async def scenario():
            outcomes = []
            for token, role, admin in (
                ("not-the-token", "worker", None),
                (TOKEN, "admin", None),
                (TOKEN, "admin", "not-the-admin-token"),
            ):
                client = TeleopClient(server.url, token, role=role, admin_token=admin)
                try:
                    await client.connect(timeout=10)
                    outcomes.append("connected")
                except OfferRefusedError as exc:
                    outcomes.append((exc.status, exc.code))
                finally:
                    await client.close()
            telemetry = await server.telemetry()
            return outcomes, telemetry

        outcomes, telemetry = run(scenario())

    assert outcomes == [(401, "bad_token"), (403, "bad_admin_token"), (403, "bad_admin_token")]
    assert telemetry["errors"]["http_bad_token"] == 1
    assert telemetry["errors"]["http_bad_admin_token"] == 2


def _first_video_codec(sdp: str) -> str:
    lines = sdp.splitlines()
    payload = next(line for line in lines if line.startswith("m=video")).split()[3]
    rtpmap = next(line for line in lines if line.startswith(f"a=rtpmap:{payload} "))
    return rtpmap.split()[1].split("/")[0]


@pytest.mark.parametrize("codec", ["vp8", "h264"])
def test_the_codec_is_selectable(tmp_path, codec):
    with teleop_server(tmp_path, video={"codec": codec}) as server:

        async def scenario():
            client = TeleopClient(server.url, TOKEN)
            await client.connect()
            await client.wait_for(lambda s: s.frames_received >= 5, 30)
            answer = client.pc.remoteDescription.sdp
            frame = client.state.latest_frame
            await client.close()
            return answer, frame

        answer, frame = run(scenario())

    assert _first_video_codec(answer) == {"vp8": "VP8", "h264": "H264"}[codec]
    assert frame is not None and frame.shape == (240, 320, 3)
