"""Who gets one of a session's peer slots, and for how long: an offer that cannot carry the
session's channels is refused before any peer is made, and a peer that never connects is
dropped after `limits.connect_timeout_s`. Either way the worker can still reach their robot."""

from __future__ import annotations

import asyncio
from typing import Any

import aiohttp
from aiortc import RTCConfiguration, RTCPeerConnection

from crowdteleop.client.connection import OfferRefusedError, TeleopClient
from crowdteleop.teleop.messages import missing_offer_sections
from tests.fixtures.teleop_process import ADMIN_TOKEN, TOKEN, ServerProcess, run, teleop_server

DATA_ONLY = "v=0\r\nm=application 9 UDP/DTLS/SCTP webrtc-datachannel\r\n"
DATA_AND_VIDEO = DATA_ONLY + "m=video 9 UDP/TLS/RTP/SAVPF 96\r\na=recvonly\r\n"


async def post_offer(server: ServerProcess, body: dict[str, Any]) -> tuple[int, dict[str, Any]]:
    """A raw `POST /offer`, as anyone holding the token may send it."""
    async with (
        aiohttp.ClientSession() as http,
        http.post(f"{server.url}/offer", json=body) as response,
    ):
        return response.status, await response.json()


async def peers_once_settled(server: ServerProcess, want: int, limit_s: float) -> int:
    """The server's peer count once it is `want`, or as it stands after `limit_s`."""
    deadline = asyncio.get_running_loop().time() + limit_s
    while True:
        peers = (await server.health())["peers"]
        if peers == want or asyncio.get_running_loop().time() > deadline:
            return peers
        await asyncio.sleep(0.2)


async def watches_video(server: ServerProcess, stay_s: float = 0.0) -> int:
    """Frames a worker's client receives once connected and while it stays `stay_s` longer
    (it raises if it cannot connect)."""
    client = TeleopClient(server.url, TOKEN, device="keyboard")
    try:
        await client.connect()
        await client.wait_for(lambda s: s.frames_received >= 3, 30)
        await asyncio.sleep(stay_s)
        return client.state.frames_received
    finally:
        await client.close()


def test_each_role_needs_the_sections_its_clients_offer():
    assert missing_offer_sections("v=0\r\n", "phone") == ["application"]
    assert missing_offer_sections("v=0\r\n", "worker") == ["application", "video"]
    assert missing_offer_sections(DATA_ONLY, "phone") == []
    assert missing_offer_sections(DATA_ONLY, "admin") == []  # a bot driving without video
    assert missing_offer_sections(DATA_ONLY, "worker") == ["video"]
    assert missing_offer_sections(DATA_AND_VIDEO, "worker") == []
    assert missing_offer_sections(DATA_AND_VIDEO.replace("\r\n", "\n"), "worker") == []


def test_empty_offers_are_refused_and_do_not_lock_the_worker_out(tmp_path):
    with teleop_server(tmp_path) as server:

        async def scenario():
            body = {"sdp": "v=0\r\n", "type": "offer", "token": TOKEN}
            refusals = [await post_offer(server, body) for _ in range(4)]
            peers = (await server.health())["peers"]
            frames = await watches_video(server)
            return refusals, peers, frames, await server.telemetry()

        refusals, peers, frames, telemetry = run(scenario())

    for status, body in refusals:
        assert (status, body["error"]) == (400, "incomplete_offer")
        assert "m=application" in body["message"]
    assert peers == 0, "a refused offer holds no slot"
    assert frames >= 3, "the worker still connects and watches the robot"
    assert telemetry["errors"]["http_incomplete_offer"] == 4


def test_a_peer_that_never_connects_frees_its_slot(tmp_path):
    limits = {"connect_timeout_s": 2.0, "max_peers": 1}
    with teleop_server(tmp_path, limits=limits) as server:

        async def scenario():
            # A real offer whose answer is never applied: the server's ICE checks are
            # answered but never nominated, so it would wait for this peer forever.
            stale = RTCPeerConnection(RTCConfiguration(iceServers=[]))
            try:
                stale.createDataChannel("control", ordered=False, maxRetransmits=0)
                stale.createDataChannel("events")
                stale.addTransceiver("video", direction="recvonly")
                await stale.setLocalDescription(await stale.createOffer())
                body = {"sdp": stale.localDescription.sdp, "type": "offer", "token": TOKEN}
                status, _answer = await post_offer(server, body)
                peers = await peers_once_settled(server, 0, limit_s=20.0)
                # The session's only slot; the worker stays well past the connect timeout.
                frames = await watches_video(server, stay_s=3 * limits["connect_timeout_s"])
            finally:
                await stale.close()
            return status, peers, frames, await server.telemetry()

        status, peers, frames, telemetry = run(scenario())

    assert status == 200, "the offer itself was fine"
    assert peers == 0, "the unconnected peer was dropped"
    assert frames >= 6, "the worker takes the freed slot and keeps watching the robot"
    assert telemetry["errors"]["peer_connect_timeout"] == 1, "a connected peer stays"


def test_only_the_phone_and_admin_bots_may_offer_data_channels_alone(tmp_path):
    with teleop_server(tmp_path) as server:

        async def scenario():
            clients = {
                "worker": TeleopClient(server.url, TOKEN, device="keyboard", video=False),
                "phone": TeleopClient(server.url, TOKEN, role="phone", device="phone"),
                "admin": TeleopClient(
                    server.url, TOKEN, role="admin", admin_token=ADMIN_TOKEN, video=False
                ),
            }
            outcomes: dict[str, str] = {}
            try:
                for role, client in clients.items():
                    try:
                        await client.connect()
                        outcomes[role] = f"hello {client.state.hello.role}"
                    except OfferRefusedError as exc:
                        outcomes[role] = f"{exc.status} {exc.code}"
                peers = (await server.health())["peers"]
            finally:
                for client in clients.values():
                    await client.close()
            return outcomes, peers

        outcomes, peers = run(scenario())

    assert outcomes == {
        "worker": "400 incomplete_offer",
        "phone": "hello phone",
        "admin": "hello admin",
    }
    assert peers == 2
