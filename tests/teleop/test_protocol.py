"""The teleop server's parts that need no network: protocol, command board, clock, matching."""

from __future__ import annotations

import asyncio
import json
import time

import numpy as np
import pytest

from crowdteleop.client.latency import FrameMatcher, LatencyTracker
from crowdteleop.control.config import ControlConfig
from crowdteleop.control.teleoperator import Teleoperator
from crowdteleop.teleop.clock import FixedRateClock
from crowdteleop.teleop.commands import CommandBoard, NotInControlError
from crowdteleop.teleop.config import TeleopConfig, VideoConfig
from crowdteleop.teleop.guard import InboundGuard
from crowdteleop.teleop.protocol import (
    ClutchEvent,
    PoseCommand,
    ProtocolError,
    json_schema,
    parse_inbound,
)

POSE = {
    "v": 1,
    "type": "pose",
    "seq": 1,
    "client_time_ms": 1.0,
    "device": "phone",
    "position": [0.0, 0.1, 0.0],
    "quaternion": [0.0, 0.0, 0.0, 1.0],
    "engaged": True,
    "gripper": False,
}


def _code(channel: str, raw: str | bytes, max_bytes: int = 4096) -> str:
    with pytest.raises(ProtocolError) as caught:
        parse_inbound(channel, raw, max_bytes)
    return caught.value.code


def test_a_valid_pose_parses():
    message = parse_inbound("control", json.dumps(POSE), 4096)
    assert isinstance(message, PoseCommand) and message.position == (0.0, 0.1, 0.0)


@pytest.mark.parametrize(
    ("raw", "code"),
    [
        ("{", "malformed"),
        (b"\xff\xfe", "malformed"),
        ("[1, 2]", "invalid"),
        (json.dumps({**POSE, "v": 2}), "version"),
        (json.dumps({**POSE, "type": "teleport"}), "unknown_type"),
        (json.dumps({**POSE, "spare": 1}), "invalid"),
        (json.dumps({**POSE, "engaged": 1}), "invalid"),
        (json.dumps({**POSE, "seq": "1"}), "invalid"),
        (json.dumps({**POSE, "seq": -1}), "invalid"),
        (json.dumps({**POSE, "position": [float("nan"), 0, 0]}), "invalid"),
        (json.dumps({**POSE, "position": [float("inf"), 0, 0]}), "invalid"),
        (json.dumps({**POSE, "position": [50.0, 0, 0]}), "invalid"),
        (json.dumps({**POSE, "quaternion": [0, 0, 0, 0]}), "invalid"),
        (json.dumps({**POSE, "device": "toaster"}), "invalid"),
        (json.dumps({k: v for k, v in POSE.items() if k != "seq"}), "invalid"),
    ],
)
def test_bad_pose_messages_are_rejected_with_a_code(raw, code):
    assert _code("control", raw) == code


def test_oversized_messages_and_foreign_channels_are_rejected():
    assert _code("control", json.dumps(POSE), max_bytes=64) == "too_large"
    assert _code("admin", json.dumps(POSE)) == "channel"


def test_events_channel_takes_events_not_poses():
    assert _code("events", json.dumps(POSE)) == "unknown_type"
    clutch = {
        "v": 1,
        "type": "clutch",
        "seq": 2,
        "client_time_ms": 0,
        "device": "phone",
        "engaged": False,
    }
    assert isinstance(parse_inbound("events", json.dumps(clutch), 4096), ClutchEvent)


def test_the_schema_covers_every_channel():
    schema = json_schema()
    assert set(schema["channels"]) == {"control", "events", "server"}
    assert schema["version"] == 1


def test_the_guard_counts_refusals_and_limits_floods():
    guard = InboundGuard(max_bytes=4096, rate=5, burst=3)
    accepted = 0
    for _ in range(10):
        try:
            guard.admit("control", json.dumps(POSE))
            accepted += 1
        except ProtocolError:
            pass
    assert accepted == 3
    assert guard.errors["rate_limited"] == 7


def _pose(
    seq: int, device: str = "phone", engaged: bool = True, position: tuple = (0.0, 0.1, 0.0)
) -> PoseCommand:
    message = {**POSE, "seq": seq, "device": device, "engaged": engaged}
    return PoseCommand.model_validate_json(json.dumps(message | {"position": list(position)}))


def test_latest_pose_wins_and_stale_ones_are_dropped():
    board = CommandBoard()
    assert board.apply_pose("p1", _pose(5))
    assert not board.apply_pose("p1", _pose(3)), "an older pose arriving late is stale"
    assert board.command().seq == 5


def test_a_late_pose_cannot_undo_a_newer_clutch_release():
    board = CommandBoard()
    board.apply_pose("p1", _pose(1))
    release = ClutchEvent(seq=3, client_time_ms=0.0, device="phone", engaged=False)
    board.apply_event("p1", release)
    board.apply_pose("p1", _pose(2, engaged=True))
    assert not board.command().engaged


def test_only_the_controlling_device_drives_until_it_hands_over():
    board = CommandBoard()
    board.apply_pose("browser", _pose(1, device="keyboard"))
    with pytest.raises(NotInControlError):
        board.apply_pose("phone", _pose(1, device="phone"))
    assert board.take_control("phone", "phone")
    assert not board.command().engaged, "a new device starts with the clutch released"
    assert board.apply_pose("phone", _pose(1, device="phone"))
    assert board.release("phone") and board.controller is None


def test_a_device_taking_over_mid_press_anchors_where_the_hand_is(lift_sim):
    """Control passes between two engaged devices (a second tab takes over a first whose clutch
    is held) between two control steps: the arm stays where it is, it does not jump to where the
    old device's anchor would put the new device's pose."""
    board, teleop = CommandBoard(), Teleoperator(lift_sim, ControlConfig())
    teleop.reset(0)
    board.apply_pose("tab-1", _pose(1, device="keyboard", position=(0.0, 0.0, 0.0)))
    teleop.step(board.command())
    board.apply_pose("tab-1", _pose(2, device="keyboard", position=(0.1, 0.0, 0.0)))
    for _ in range(30):  # the hand follows the first tab 10 cm
        teleop.step(board.command())
    hand = lift_sim.robot_state().end_effector.position

    board.take_control("tab-2", "keyboard")  # both before the next control step
    board.apply_pose("tab-2", _pose(1, device="keyboard", position=(0.0, 0.0, 0.0)))
    for _ in range(30):
        teleop.step(board.command())

    assert np.linalg.norm(lift_sim.robot_state().end_effector.position - hand) < 0.01


def test_the_clock_keeps_its_rate_and_skips_rather_than_bursts():
    async def run():
        clock = FixedRateClock(50.0)
        started = time.monotonic()
        for tick in range(10):
            due = await clock.wait_next()
            if tick == 3:
                await asyncio.sleep(0.07)  # a long tick: 3.5 periods
            clock.finished(due)
        return clock.stats, time.monotonic() - started

    stats, elapsed = asyncio.run(run())
    assert stats.overruns == 1
    assert stats.skipped >= 2
    assert elapsed == pytest.approx(0.02 * (9 + stats.skipped), abs=0.03)


def test_frames_are_matched_to_commands_despite_an_unknown_rtp_offset():
    matcher = FrameMatcher()
    pts_values = [0, 4493, 9012, 13467, 18020, 22475]
    for seq, pts in enumerate(pts_values, start=10):
        matcher.add_tag(pts, seq)
    offset = 123_456_789
    seen = [matcher.command_seq_of(pts + offset) for pts in pts_values]
    assert seen[:2] == [None, None], "two frames cannot fix the offset"
    assert seen[2:] == [12, 13, 14, 15]


def test_latency_counts_each_command_once_from_its_first_frame():
    tracker = LatencyTracker()
    for seq in (1, 2, 3):
        tracker.command_sent(seq, 10.0 + seq * 0.01)
    assert tracker.frame_shown(2, 10.10) == pytest.approx([90.0, 80.0])
    assert tracker.frame_shown(2, 10.20) == []
    assert tracker.frame_shown(3, 10.25) == pytest.approx([220.0])


def test_configs_refuse_what_aiortc_would_clamp_or_the_sim_could_not_run():
    with pytest.raises(ValueError, match="bitrates"):
        VideoConfig(codec="h264", min_bitrate_bps=250_000)
    with pytest.raises(ValueError, match="action mode"):
        TeleopConfig.model_validate(
            {"control": {"controller": "osc"}, "sim": {"action_mode": "joint-velocity"}}
        )
    # named once: the simulation's action mode follows the controller
    assert TeleopConfig.model_validate({"control": {"controller": "osc"}}).sim.action_mode == (
        "osc-pose"
    )


def test_mdns_candidates_are_dropped_from_offers_and_nothing_else():
    from crowdteleop.teleop.server import without_mdns_candidates

    offer = "\r\n".join(
        [
            "v=0",
            "a=candidate:1 1 udp 2113937151 3f1c7a2e-1111-4c1d.local 54321 typ host",
            "a=candidate:2 1 udp 2113939711 192.168.1.20 54322 typ host",
            "a=candidate:3 1 udp 1677729535 203.0.113.7 54323 typ srflx raddr 0.0.0.0 rport 0",
            "a=end-of-candidates",
            "",
        ]
    )
    kept = without_mdns_candidates(offer)
    assert ".local" not in kept
    assert "192.168.1.20" in kept and "203.0.113.7" in kept and "a=end-of-candidates" in kept


def _step(index: int, success: bool = False):
    import numpy as np

    from crowdteleop.recording.episode_file import StepRecord

    return StepRecord(
        index=index,
        state=np.zeros(5),
        action=np.zeros(2),
        command={"seq": index},
        server_time=0.0,
        step_duration_s=0.001,
        reward=float(success),
        success=success,
        contacts=[],
    )


def _tracker(tmp_path, time_limit_s: float = 1.0):
    from crowdteleop.teleop.episode import EpisodeTracker

    return EpisodeTracker(
        control_dt=0.05,
        time_limit_s=time_limit_s,
        success_hold_steps=3,
        recordings=tmp_path,
        metadata={"session_id": "units"},
    )


def test_an_episode_starts_with_the_clutch_and_ends_after_success_is_held(tmp_path):
    tracker = _tracker(tmp_path)
    assert not tracker.maybe_start(engaged=False) and tracker.state == "ready"
    assert tracker.maybe_start(engaged=True) and tracker.state == "running"
    outcomes = [tracker.record(_step(i, success=i >= 2)) for i in range(5)]
    assert outcomes == [None, None, None, None, "success"], "held for 3 steps, as configured"
    finished = tracker.end("success")
    assert finished.steps == 5 and tracker.successes == 1 and tracker.state == "ready"
    assert finished.recorder.finalize(finished.outcome).exists()


def test_an_episode_times_out_and_a_disconnect_ends_it(tmp_path):
    tracker = _tracker(tmp_path, time_limit_s=0.2)
    tracker.maybe_start(engaged=True)
    assert [tracker.record(_step(i)) for i in range(4)] == [None, None, None, "timeout"]
    tracker.end("timeout")
    tracker.maybe_start(engaged=True)
    tracker.record(_step(0))
    finished = tracker.end("disconnect")
    assert finished.outcome == "disconnect" and finished.number == 2
    assert tracker.end("reset") is None, "nothing runs: nothing to end"


def test_the_bot_presses_the_clutch_again_only_once_the_server_applied_its_release():
    """After a reset the server must see the bot let go before the next press: it applies
    only the latest pose of each step, and poses of the last episode may still be arriving
    (pressed). A press that follows the release too soon leaves the server anchored on a
    stale pose, and the bot steering an arm that is not where it thinks (it stalls)."""
    from crowdteleop.client.bot import Bot
    from crowdteleop.client.connection import TeleopClient
    from crowdteleop.sim import SimConfig, make_simulation
    from crowdteleop.teleop.protocol import Hello, PrivilegedState
    from crowdteleop.teleop.session import _privileged

    sim = make_simulation(SimConfig(task="lift"))
    try:
        sim.reset(0)
        scene = _privileged(sim, sim.robot_state().end_effector)
    finally:
        sim.close()
    client = TeleopClient("http://127.0.0.1:9", "worker-token", role="admin", admin_token="x")
    sent: list[dict] = []
    client.send_raw = lambda channel, message: sent.append(message) or True  # type: ignore[method-assign]
    client.state.hello = Hello(
        session_id="s", peer_id="p", role="admin", task="lift", instruction="", fps=20.0,
        width=320, height=240, controlling_device="bot",
    )  # fmt: skip
    Bot(client, seed=0)  # drives through client.on_privileged, as messages arrive

    def server_step(step: int, applied_seq: int) -> dict:
        client.on_privileged(PrivilegedState(step=step, scene=1, command_seq=applied_seq, **scene))
        return sent[-1]

    release = server_step(0, applied_seq=0)  # a new scene: let go
    assert release["engaged"] is False
    for step in (1, 2):  # the server still applies older (pressed) poses: keep letting go
        assert server_step(step, applied_seq=release["seq"] - 1)["engaged"] is False
    assert server_step(3, applied_seq=release["seq"])["engaged"] is True  # release applied
