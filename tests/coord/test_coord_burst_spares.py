"""Warm spares for bursts (`spare_servers: auto`): every free slot kept warm, the spares
started together, a burst of as many workers as there are slots each given a running robot
without a cold start; and what the pages are told while a robot is prepared."""

from __future__ import annotations

import asyncio
import os
import re
import time
from datetime import datetime

import httpx
import pytest

from crowdteleop.coord.fleet.startup import (
    DEFAULT_SERVER_BYTES,
    DEFAULT_START_S,
    StartupStats,
    resident_bytes,
)
from crowdteleop.coord.service.coordinator import spread
from tests.fixtures.coord import (
    Api,
    FakeLauncher,
    Worker,
    coord_config,
    coord_server,
    in_process_app,
)

CAPACITY = 3
SPARE_LOG = re.compile(r"^(\S+ \S+) INFO \S+ spare (spare-\w+) (starting|ready) for ")


def spare_times(log: str) -> dict[str, dict[str, datetime]]:
    """spare id -> {"starting": when, "ready": when}, from the coordinator's log."""
    times: dict[str, dict[str, datetime]] = {}
    for line in log.splitlines():
        if found := SPARE_LOG.match(line):
            when = datetime.strptime(found[1], "%Y-%m-%d %H:%M:%S,%f")
            times.setdefault(found[2], {})[found[3]] = when
    return times


@pytest.mark.slow
def test_auto_spares_warm_every_slot_together_and_a_burst_gets_them_all(tmp_path):
    config = {"capacity": CAPACITY, "spare_servers": "auto"}
    with coord_server(tmp_path, **config) as server:

        async def scenario() -> list[dict]:
            async with httpx.AsyncClient(base_url=server.url, timeout=60) as http:
                health = (await http.get("/health")).json()
                assert health["spares"] >= 1, f"READY before the first warm robot: {health}"
                deadline = time.monotonic() + 30
                while (await http.get("/health")).json()["spares"] < CAPACITY:
                    assert time.monotonic() < deadline, "the spares never all came up"
                    await asyncio.sleep(0.2)
                campaign = (await http.get("/api/campaigns/default")).json()
                assert campaign["robot"]["eta_s"] == 0, campaign["robot"]
                workers = [Worker(http, {"PROLIFIC_PID": f"burst{n}"}) for n in range(CAPACITY)]
                await asyncio.gather(*(w.start() for w in workers))
                views = await asyncio.gather(*(w.until("ready", 10) for w in workers))
                for worker in workers:
                    await worker.stop()
                return views

        views = asyncio.run(scenario())
        log = server.log()
    assert len({v["session_id"] for v in views}) == CAPACITY
    assert all(v["preparing"] is None for v in views), "a ready session prepares nothing"
    spares = spare_times(log)
    first = sorted(spares.values(), key=lambda t: t["starting"])[:CAPACITY]
    assert len(first) == CAPACITY and all("ready" in t for t in first), spares
    assert max(t["starting"] for t in first) < min(t["ready"] for t in first), (
        f"the spares started one after another, not together: {first}"
    )
    sessions = {v["session_id"] for v in views}
    cold = [line for line in log.splitlines() if any(f" for {sid} at " in line for sid in sessions)]
    assert not cold, f"sessions of the burst were started cold: {cold}"


def test_a_cold_start_is_counted_down_and_the_join_page_told(tmp_path):
    """No spares: the join page hears a start's whole length, the session's page the rest of
    it (the default 10 s before any start was measured), then a measured one."""
    config = coord_config(tmp_path, capacity=1, spare_servers=0)
    with in_process_app(config, FakeLauncher(start_delay_s=1.0)) as client:
        api = Api(client)
        robot = client.get("/api/campaigns/default").json()["robot"]
        assert robot == {"eta_s": 10.0, "total_s": 10.0}
        token = api.join({"PROLIFIC_PID": "cold1"})["worker_token"]
        view = api.new_session(token)
        assert view["state"] == "starting", view
        assert 1.0 <= view["preparing"]["eta_s"] <= 10.0
        assert view["preparing"]["total_s"] == 10.0
        ready = api.wait_state(token, view["session_id"], "ready")
        assert ready["preparing"] is None
        assert client.get("/api/campaigns/default").json()["robot"] is None, "every slot held"
        api.client.delete(f"/api/sessions/{view['session_id']}", headers=api.auth(token))
        robot = client.get("/api/campaigns/default").json()["robot"]
        assert 0.9 <= robot["total_s"] <= 3.0, f"the start measured (about 1 s): {robot}"
        served = client.get("/views.json").json()  # what the pages check these against
        assert served["SessionView"]["properties"]["preparing"]
        assert served["CampaignView"]["properties"]["robot"]


class CountingLauncher(FakeLauncher):
    """The fake launcher, counting the starts under way at once."""

    def __init__(self, start_delay_s: float) -> None:
        super().__init__(start_delay_s)
        self.running = self.most = 0

    async def start(self, config):
        self.running += 1
        self.most = max(self.most, self.running)
        try:
            return await super().start(config)
        finally:
            self.running -= 1


def test_auto_spares_start_in_parallel_up_to_the_free_slots(tmp_path):
    """Capacity 4: four spares, started at once; a worker takes one and none replaces it (the
    slot it holds is not free)."""
    config = coord_config(tmp_path, capacity=4, spare_servers="auto")
    launcher = CountingLauncher(start_delay_s=0.5)
    with in_process_app(config, launcher) as client:
        deadline = time.monotonic() + 20
        while client.get("/health").json()["spares"] < 4:
            assert time.monotonic() < deadline, "the spares never all came up"
            time.sleep(0.05)
        assert launcher.most == 4, f"at most {launcher.most} spares started at once"
        time.sleep(0.5)
        assert client.get("/health").json()["spares"] == 4, "no more than the free slots"
        api = Api(client)
        token = api.join({"PROLIFIC_PID": "warm1"})["worker_token"]
        sid = api.new_session(token)["session_id"]
        api.wait_state(token, sid, "ready", timeout=3)
        time.sleep(0.5)
        assert client.get("/health").json()["spares"] == 3, "a taken spare leaves no new one"
    assert len(launcher.handles) == 4


def test_spares_are_spread_over_the_kinds_the_campaigns_hand_out_next_first():
    kinds = [("lift", "Sawyer", "ik-velocity"), ("stack", "Sawyer", "ik-velocity")]
    assert spread(3, kinds) == {kinds[0]: 2, kinds[1]: 1}
    assert spread(0, kinds) == {kinds[0]: 0, kinds[1]: 0}
    assert spread(4, []) == {}


def test_start_times_are_the_median_of_those_measured_and_memory_the_largest():
    stats = StartupStats()
    assert stats.typical_start_s() == DEFAULT_START_S
    assert stats.remaining_s(DEFAULT_START_S + 5) == 1.0, "never 'now' before it is ready"
    for seconds in (4.0, 9.0, 5.0):
        stats.started(seconds)
    assert stats.typical_start_s() == 5.0
    assert stats.remaining_s(1.5) == 3.5
    assert stats.server_bytes == DEFAULT_SERVER_BYTES, "nothing measured yet"
    stats.started(6.0, pid=os.getpid())  # this process stands in for a server
    assert stats.server_bytes != DEFAULT_SERVER_BYTES and resident_bytes(os.getpid())
