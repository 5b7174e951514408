"""Thousands of random and malformed messages on every channel: the session shrugs them off."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from crowdteleop.client.connection import TeleopClient
from tests.fixtures.teleop_process import ADMIN_TOKEN, TOKEN, ServerProcess, teleop_server

FUZZ_MESSAGES = 10_500
KNOWN_CODES = {
    "malformed",
    "invalid",
    "unknown_type",
    "version",
    "too_large",
    "channel",
    "rate_limited",
    "not_in_control",
    "stale_input",  # the fuzzer's poses are dated 1 ms after 1970
    "not_worker",  # video reports from the fuzzer (an admin)
    "bad_pong",
}

VALID = {
    "pose": {
        "v": 1,
        "type": "pose",
        "seq": 1,
        "client_time_ms": 1.0,
        "device": "bot",
        "position": [0.0, 0.0, 0.0],
        "quaternion": [0.0, 0.0, 0.0, 1.0],
        "engaged": True,
        "gripper": False,
    },
    "clutch": {
        "v": 1,
        "type": "clutch",
        "seq": 1,
        "client_time_ms": 1.0,
        "device": "bot",
        "engaged": True,
    },
    "gripper": {
        "v": 1,
        "type": "gripper",
        "seq": 1,
        "client_time_ms": 1.0,
        "device": "bot",
        "closed": True,
    },
    "ping": {"v": 1, "type": "ping", "id": 1, "client_time_ms": 1.0},
    "latency": {"v": 1, "type": "latency", "samples_ms": [12.0], "fps": 20.0},
    "take_control": {"v": 1, "type": "take_control", "device": "bot"},
}

json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=20),
    lambda inner: (
        st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=8), inner, max_size=5)
    ),
    max_leaves=12,
)


@st.composite
def mutated_messages(draw: st.DrawFn) -> str:
    """A valid message with one field replaced, removed or added: the hardest to tell apart."""
    message = dict(draw(st.sampled_from(list(VALID.values()))))
    key = draw(st.sampled_from([*message, "extra"]))
    action = draw(st.sampled_from(["replace", "remove", "add"]))
    if action == "remove":
        message.pop(key, None)
    else:
        message[key] = draw(json_values)
    return json.dumps(message)  # NaN and Infinity come through as JSON's non-standard tokens


payloads = st.one_of(
    mutated_messages(),
    json_values.map(json.dumps),
    st.binary(max_size=200),
    st.text(max_size=200),
    st.integers(4_200, 9_000).map(lambda n: '{"v": 1, "type": "pose", "pad": "' + "x" * n + '"}'),
)

# runs alone under xdist: the control loop keeps its rate under a flood
pytestmark = pytest.mark.exclusive


class LoopThread:
    """An event loop in a thread, so hypothesis (synchronous) can feed live aiortc clients."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()

    def run(self, coroutine, timeout: float = 120):
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop).result(timeout)

    def call(self, function, *args) -> None:
        self.loop.call_soon_threadsafe(function, *args)

    def stop(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(10)


async def _drained(server: ServerProcess, quiet_s: float = 3.0, limit_s: float = 120.0) -> dict:
    """Telemetry once the server's refusal counts stopped growing: SCTP in Python delivers a
    burst of thousands of messages over several seconds."""
    deadline = asyncio.get_running_loop().time() + limit_s
    last, steady = None, 0.0
    while True:
        telemetry = await server.telemetry()
        total = sum(telemetry["errors"].values())
        steady = steady + 0.5 if total == last else 0.0
        if steady >= quiet_s or asyncio.get_running_loop().time() > deadline:
            return telemetry
        last = total
        await asyncio.sleep(0.5)


@pytest.fixture(scope="module")
def fuzz_session(tmp_path_factory) -> Iterator[tuple[ServerProcess, LoopThread, dict]]:
    limits = {"messages_per_second": 20_000, "burst": 20_000}  # let the flood reach the parser
    with teleop_server(tmp_path_factory.mktemp("fuzz"), limits=limits) as server:
        loop = LoopThread()
        clients = {
            "watcher": TeleopClient(server.url, TOKEN, device="keyboard"),
            "fuzzer": TeleopClient(server.url, TOKEN, role="admin", admin_token=ADMIN_TOKEN),
        }
        for client in clients.values():
            loop.run(client.connect())
        yield server, loop, clients
        for client in clients.values():
            loop.run(client.close())
        loop.stop()


@pytest.mark.slow
# aiortc's ICE code, running in the client thread, uses `random` while hypothesis generates.
@pytest.mark.filterwarnings("ignore::hypothesis.errors.HypothesisDeprecationWarning")
def test_ten_thousand_bad_messages_leave_the_session_running(fuzz_session):
    server, loop, clients = fuzz_session
    fuzzer, watcher = clients["fuzzer"], clients["watcher"]
    before = loop.run(server.telemetry())
    frames_before = watcher.state.frames_received
    sent = {"n": 0, "reliable": 0}

    @settings(
        max_examples=FUZZ_MESSAGES,
        deadline=None,
        database=None,
        phases=[Phase.generate],
        suppress_health_check=list(HealthCheck),
    )
    @given(channel=st.sampled_from(["control", "events", "admin"]), payload=payloads)
    def send_one(channel, payload):
        loop.call(fuzzer.send_raw, channel, payload)
        sent["n"] += 1
        sent["reliable"] += channel != "control"  # control may drop messages, by design
        time.sleep(0.001)  # ~700 messages a second: a flood, at a pace SCTP in Python delivers

    send_one()
    after = loop.run(_drained(server))
    health = loop.run(server.health())

    assert sent["n"] >= 10_000
    assert server.alive() and health["status"] == "ok" and health["spool_pending"] == 0
    refused = sum(after["errors"].values()) - sum(before["errors"].values())
    assert refused > sent["reliable"] * 0.5, "most fuzz is refused and counted"
    assert set(after["errors"]) - {"stale", "http_bad_token"} <= KNOWN_CODES
    assert {e.code for e in fuzzer.state.errors} <= KNOWN_CODES and fuzzer.state.errors
    ticks = after["ticks"] - before["ticks"]
    overruns = after["overruns"] - before["overruns"]
    assert after["loop_hz"] > 18, "the control loop kept its rate"
    assert overruns <= max(3, 0.05 * ticks)
    assert watcher.state.frames_received > frames_before, "the video kept flowing"


@pytest.mark.slow
def test_after_the_fuzz_a_worker_still_drives_the_arm(fuzz_session):
    _server, loop, clients = fuzz_session
    watcher = clients["watcher"]

    async def drive():
        watcher.take_control()
        watcher.request("start")  # the fuzzer may have sent a valid "stop"
        await asyncio.sleep(1.0)
        before = np.array(watcher.state.status.end_effector)
        for i in range(31):
            offset = np.array([0.0, 0.0, 0.06]) * min(1.0, i / 18)
            watcher.send_pose(offset, (0, 0, 0, 1), True, False)
            await asyncio.sleep(0.05)
        await asyncio.sleep(1.0)
        return np.array(watcher.state.status.end_effector) - before

    moved = loop.run(drive())
    assert moved[2] == pytest.approx(0.06, abs=0.02)


def test_exact_counts_per_kind_of_bad_message(tmp_path):
    bad = {
        "malformed": "{not json",
        "version": json.dumps({**VALID["ping"], "v": 7}),
        "unknown_type": json.dumps({"v": 1, "type": "teleport"}),
        "invalid": json.dumps({**VALID["ping"], "id": -5}),
        "too_large": json.dumps({**VALID["ping"], "pad": "x" * 10_000}),
    }
    with teleop_server(tmp_path) as server:

        async def scenario():
            client = TeleopClient(server.url, TOKEN)
            await client.connect()
            for raw in bad.values():
                for _ in range(20):
                    client.send_raw("events", raw)
                await asyncio.sleep(1.2)  # under the rate limit and the error-event budget
            await asyncio.sleep(1.0)
            telemetry = await server.telemetry()
            codes = [e.code for e in client.state.errors]
            await client.close()
            return telemetry, codes

        loop = asyncio.new_event_loop()
        telemetry, codes = loop.run_until_complete(scenario())
        loop.close()

    for code in bad:
        assert telemetry["errors"][code] == 20, code
        assert codes.count(code) == 20, code
