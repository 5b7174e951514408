"""A teleop server's episode reports wait in an outbox until the coordinator confirms each one
(issue 30): a coordinator that is down, or an address a node cannot reach, costs no
demonstration; the worker hears it once; a refused report is not retried forever.

The coordinator's side is a small HTTP endpoint on loopback that records what it is sent (its
real `/internal/episodes` is exercised by the coordinator's tests and the Ray deployment's)."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from aiohttp import web

from crowdteleop.teleop.messages import EpisodeAck, EpisodeReport
from crowdteleop.teleop.protocol import EpisodeFeedback
from crowdteleop.teleop.report import (
    MAX_BACKOFF_S,
    REQUEST_TIMEOUT_S,
    PendingReport,
    ReportOutbox,
)
from tests.fixtures.s3 import free_port


def report(number: int) -> EpisodeReport:
    return EpisodeReport(
        session_id="s1",
        worker_id="w1",
        episode=number,
        episode_id=f"ep{number}",
        outcome="success",
        steps=70,
        duration_s=3.5,
        uri=f"file:///data/ep{number}.hdf5",
        telemetry={},
    )


@asynccontextmanager
async def coordinator(
    port: int, status: int = 200, answer: dict | None = None
) -> AsyncIterator[list[str]]:
    """Answers every report with `status` and `answer` (its episode id filled in); yields the
    episode ids it heard, in order."""
    heard: list[str] = []

    async def episodes(request: web.Request) -> web.Response:
        heard.append((await request.json())["episode_id"])
        body = {**answer, "episode_id": heard[-1]} if answer is not None else {}
        return web.json_response(body, status=status)

    app = web.Application()
    app.add_routes([web.post("/internal/episodes", episodes)])
    runner = web.AppRunner(app)
    await runner.setup()
    await web.TCPSite(runner, "127.0.0.1", port).start()
    try:
        yield heard
    finally:
        await runner.cleanup()


# An attempt may take up to a request's timeout on a loaded machine, then back off: what the
# waits allow (they test order and exactly-once; how soon is benchmarks/deploy.py's figure).
PATIENCE_S = REQUEST_TIMEOUT_S + MAX_BACKOFF_S + 5.0


async def until(condition, timeout_s: float = PATIENCE_S) -> None:
    deadline = asyncio.get_running_loop().time() + timeout_s
    while not condition():
        assert asyncio.get_running_loop().time() < deadline, "never happened"
        await asyncio.sleep(0.02)


def test_reports_wait_for_a_coordinator_that_is_down_and_arrive_once_in_order():
    async def scenario() -> None:
        port = free_port()
        url = f"http://127.0.0.1:{port}/internal/episodes"
        told: list[str] = []
        outbox = ReportOutbox(on_unreachable=told.append)
        for number in (1, 2, 3):  # the coordinator is down (a restart): nobody answers
            outbox.put(PendingReport(url, "token", report(number)))
        await until(lambda: outbox.failed_attempts >= 3)  # ~3.5 s of backoff: past the old 5
        assert outbox.pending == 3 and outbox.unreachable == url
        assert told == [url], "the worker is told once, not per attempt"
        async with coordinator(port) as heard:
            await until(lambda: outbox.pending == 0)
            assert heard == ["ep1", "ep2", "ep3"], "each once, in the order they were stored"
            assert outbox.unreachable is None and outbox.delivered == 3
            outbox.put(PendingReport(url, "token", report(4)))
            await until(lambda: outbox.pending == 0)
            assert heard[-1] == "ep4"
            await outbox.close()

    asyncio.run(scenario())


def test_each_answer_reaches_on_ack_with_the_workers_feedback():
    feedback = EpisodeFeedback(episode=1, time_s=6.5, median_time_s=8.0, tip="Well done.")
    answer = {
        "duplicate": False,
        "demos_done": 1,
        "demos_required": 3,
        "completed": False,
        "feedback": feedback.model_dump(mode="json"),
    }

    async def scenario() -> list[EpisodeAck]:
        port = free_port()
        url = f"http://127.0.0.1:{port}/internal/episodes"
        acks: list[EpisodeAck] = []
        outbox = ReportOutbox(on_unreachable=lambda _url: None, on_ack=acks.append)
        async with coordinator(port, answer=answer):
            for number in (1, 2):
                outbox.put(PendingReport(url, "token", report(number)))
            await until(lambda: outbox.pending == 0)
        async with coordinator(port):  # an answer that is no EpisodeAck: still delivered
            outbox.put(PendingReport(url, "token", report(3)))
            await until(lambda: outbox.pending == 0)
        await outbox.close()
        assert outbox.delivered == 3
        return acks

    acks = asyncio.run(scenario())
    assert [ack.episode_id for ack in acks] == ["ep1", "ep2"]
    assert acks[0].feedback == feedback


def test_a_refused_report_is_dropped_and_the_next_one_goes(caplog):
    async def scenario() -> None:
        port = free_port()
        url = f"http://127.0.0.1:{port}/internal/episodes"
        outbox = ReportOutbox(on_unreachable=lambda _url: None)
        async with coordinator(port, status=403) as heard:
            outbox.put(PendingReport(url, "another session's token", report(1)))
            outbox.put(PendingReport(url, "another session's token", report(2)))
            await until(lambda: outbox.pending == 0)
            await outbox.close()
        assert heard == ["ep1", "ep2"], "a 4xx is not retried: it will not change"
        assert outbox.refused == 2 and outbox.delivered == 0

    caplog.set_level(logging.ERROR)
    asyncio.run(scenario())
    assert "episode report refused (403)" in caplog.text


def test_a_report_address_nothing_answers_is_said_at_start_and_undelivered_ones_named(caplog):
    async def scenario() -> None:
        url = f"http://127.0.0.1:{free_port()}/internal/episodes"  # a node's view of loopback
        told: list[str] = []
        outbox = ReportOutbox(on_unreachable=told.append)
        assert not await outbox.probe(url)
        assert told == [url] and outbox.unreachable == url
        outbox.put(PendingReport(url, None, report(7)))
        await outbox.close(grace_s=0.5)
        assert outbox.pending == 1

    caplog.set_level(logging.ERROR)
    asyncio.run(scenario())
    assert "cannot reach the coordinator" in caplog.text and "internal_url" in caplog.text
    assert "episode ep7 (success) was stored at file:///data/ep7.hdf5 but never reported" in (
        caplog.text
    )


def test_the_probe_takes_any_answer_as_reachable():
    async def scenario() -> None:
        port = free_port()
        outbox = ReportOutbox(on_unreachable=lambda _url: None)
        async with coordinator(port):  # a GET on the POST route: 405, but it answers
            assert await outbox.probe(f"http://127.0.0.1:{port}/internal/episodes")
        assert outbox.unreachable is None

    asyncio.run(scenario())
