"""One bot that is a worker: it joins through the coordinator exactly as a browser does (study
link, session, queue, WebRTC offer through the coordinator, heartbeats, a phone paired with
the page's code for some), drives its robot with a scripted operator until the campaign's
demonstrations are done, and reports what a worker would have lived through."""

from __future__ import annotations

import asyncio
import contextlib
import time
from dataclasses import dataclass, field
from pathlib import Path

import aiohttp
import numpy as np

from crowdteleop.client.bot import Bot
from crowdteleop.client.connection import ConnectionLostError, TeleopClient
from crowdteleop.control.scripted.skills import style_for
from crowdteleop.crowd.api import WorkerApi
from crowdteleop.teleop.messages import OfferAnswer
from crowdteleop.vocab import InjectedFault, SkillName


@dataclass
class CrowdSettings:
    """What every bot of a crowd shares."""

    coordinator_url: str
    admin_token: str  # the bot reads object poses through the admin API, as `crowdteleop bot`
    campaign: str | None = None
    task: str | None = None  # if set, a session of another task is reported as an error
    study_id: str = "crowd-bots"
    queue_timeout_s: float = 600.0
    session_timeout_s: float = 900.0
    phone_every: int = 0  # every k-th bot drives from a paired phone (0: none)
    # The bots' skills (`control.scripted.skills`), taken in turn: bot i has skills[i % n].
    # Empty: every bot is the default scripted operator.
    skills: tuple[SkillName, ...] = ()
    # Faults the bots make in every demonstration (`control.scripted.skills.FAULTS`), taken
    # in turn like the skills: bot i makes faults[i % n]. Empty: none.
    faults: tuple[InjectedFault, ...] = ()
    # Load tests: drive for warmup_s + window_s after the first frame, measure in the window,
    # then leave (no completion code expected).
    window_s: float | None = None
    warmup_s: float = 5.0
    # The window starts when this file exists (all bots ready); without a window, the bots
    # start driving then (a test decides when the demonstrations begin, not the clock).
    start_gate: Path | None = None


@dataclass
class WorkerReport:
    """One bot's visit, in the figures a worker's experience is judged by."""

    name: str
    skill: SkillName | None = None  # the synthetic worker's skill (None: the default operator)
    fault: InjectedFault | None = None  # the fault it makes in each demonstration, if any
    session_id: str = ""
    task: str = ""
    device: str = "bot"  # what drove: the page (bot) or a paired phone
    queued_s: float = 0.0  # from joining to the session being ready
    first_frame_s: float | None = None  # from joining to the first video frame
    episode_s: list[float] = field(default_factory=list)  # wall time of each episode
    outcomes: list[str] = field(default_factory=list)
    latency_ms: list[float] = field(default_factory=list)  # control-to-frame, per frame
    fps: float = 0.0
    completion_code: str | None = None
    error: str | None = None
    reconnects: int = 0  # new robots after a crash or hang, as the page reconnects
    notices: list[str] = field(default_factory=list)  # what the coordinator told meanwhile

    @property
    def latency_p50_ms(self) -> float | None:
        return float(np.median(self.latency_ms)) if self.latency_ms else None

    @property
    def latency_p95_ms(self) -> float | None:
        return float(np.percentile(self.latency_ms, 95)) if self.latency_ms else None


MAX_RECONNECTS = 5  # a worker whose robot or network fails more often than this gives up
TOLD_CODES = {"not_saved", "recording_failed"}  # what a worker's page shows and a bot reports


class _RobotReplacedError(Exception):
    """The coordinator gave the session a new teleop server (the old one crashed or hung)."""


async def _drive(
    api: WorkerApi, report: WorkerReport, settings: CrowdSettings, index: int, joined_at: float
) -> None:
    view = await api.until_ready(settings.queue_timeout_s)
    report.queued_s = time.monotonic() - joined_at
    report.task = view.task
    if settings.task is not None and view.task != settings.task:
        raise ValueError(f"the campaign assigned {view.task!r}, not {settings.task!r}")
    while True:
        try:
            await _one_robot(api, report, settings, index, joined_at)
            return
        except (_RobotReplacedError, ConnectionLostError) as exc:
            # As the page does: show the notice, wait for the new robot, connect again; or,
            # the connection lost, as its worker does: reload.
            if report.reconnects >= MAX_RECONNECTS:
                raise ConnectionError(f"gave up after {MAX_RECONNECTS} reconnects") from exc
            report.reconnects += 1
            await api.until_ready(settings.queue_timeout_s)


async def _one_robot(
    api: WorkerApi, report: WorkerReport, settings: CrowdSettings, index: int, joined_at: float
) -> None:
    """Connect to the session's current teleop server and drive it."""
    access = await api.teleop_access(settings.admin_token)
    worker = TeleopClient(access.url, "", role="worker", device="bot", offer_via=api.offer)
    observer = TeleopClient(
        access.url, access.token, role="admin", admin_token=access.admin_token, video=False
    )
    clients = [worker, observer]
    try:
        await worker.connect()
        await observer.connect()
        driver = worker
        if settings.phone_every and index % settings.phone_every == settings.phone_every - 1:
            phone_token = await api.pair_phone()

            async def phone_offer(sdp: str) -> OfferAnswer:
                return await api.phone_offer(phone_token, sdp)

            driver = TeleopClient(
                access.url, "", role="phone", device="phone", offer_via=phone_offer
            )
            clients.append(driver)
            await driver.connect()
            driver.take_control()
            worker.latency = driver.latency  # the phone commands, the page shows the frames
            report.device = "phone"
        await worker.wait_for(lambda state: state.frames_received > 0, 60)
        if report.first_frame_s is None:
            report.first_frame_s = time.monotonic() - joined_at
        if settings.window_s is None:  # the bot drives from the moment it exists
            await _wait_for_gate(settings.start_gate)
        bot = Bot(
            driver,
            style=style_for(report.skill, report.fault),
            seed=index + 1000 * report.reconnects,
            observer=observer,
        )
        streaming = asyncio.create_task(bot.stream(30.0))
        try:
            if settings.window_s is not None:
                await _wait_for_gate(settings.start_gate)
                await _for_a_window(worker, report, settings.warmup_s, settings.window_s)
            else:
                try:
                    await _until_done(api, worker, report, settings.session_timeout_s)
                finally:  # what the worker saw, also when it did not finish
                    report.latency_ms += worker.latency.samples_ms
                    report.fps = worker.state.fps()
        finally:
            streaming.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await streaming
    finally:
        for client in clients:
            await client.close()


async def _wait_for_gate(gate: Path | None) -> None:
    """A load test's bots measure the same window, and a test's bots begin their
    demonstrations together: the gate opens when every robot is live."""
    while gate is not None and not gate.exists():
        await asyncio.sleep(0.1)


async def _for_a_window(
    worker: TeleopClient, report: WorkerReport, warmup_s: float, window_s: float
) -> None:
    """Latency and frame rate over a window after a warm-up, as a load test measures them."""
    await asyncio.sleep(warmup_s)
    first_sample, first_frames = len(worker.latency.samples_ms), worker.state.frames_received
    started = time.monotonic()
    await asyncio.sleep(window_s)
    report.fps = (worker.state.frames_received - first_frames) / (time.monotonic() - started)
    report.latency_ms = list(worker.latency.samples_ms[first_sample:])
    report.outcomes = [episode.outcome for episode in worker.state.episodes]


@dataclass
class _Heard:
    """How much of what the server told this connection the report already holds."""

    last_end: float  # when the last episode ended (or the robot was first driven)
    episodes: int = 0
    errors: int = 0

    def take(self, worker: TeleopClient, report: WorkerReport) -> None:
        """Episodes ended and errors told since the last look go into the report; a recording
        failure stops the worker, as the page does."""
        episodes = worker.state.episodes
        while self.episodes < len(episodes):
            now = time.monotonic()
            report.outcomes.append(episodes[self.episodes].outcome)
            report.episode_s.append(now - self.last_end)
            self.last_end, self.episodes = now, self.episodes + 1
        for event in worker.state.errors[self.errors :]:
            self.errors += 1
            if event.code in TOLD_CODES:
                report.notices.append(event.message)
            if event.code == "recording_failed":  # the page shows it; the worker stops
                raise ConnectionError(f"the server said: {event.message}")


async def _until_done(
    api: WorkerApi, worker: TeleopClient, report: WorkerReport, timeout_s: float
) -> None:
    """Episodes as they end, until the coordinator hands over the completion code."""
    started = time.monotonic()
    heard = _Heard(last_end=started)
    code_at: float | None = None
    robot_since = api.view.ready_at if api.view is not None else None
    while True:
        heard.take(worker, report)
        if worker.lost:  # the page says "reload to reconnect"; its worker does
            report.notices.append("the connection to the robot was lost")
            raise ConnectionLostError("the connection to the robot was lost")
        view = await api.refresh()
        if view.state in ("queued", "starting") or view.ready_at != robot_since:
            report.notices.append(view.notice or "")
            raise _RobotReplacedError(view.notice)
        if view.completion_code:
            report.completion_code = view.completion_code
            if report.outcomes.count("success") >= view.demos_required:
                return
            # The coordinator heard of the last demonstration (stored, then reported) before
            # the page heard of its end: wait for the page a little.
            code_at = code_at or time.monotonic()
            if time.monotonic() - code_at > 10:
                raise ConnectionError("a completion code, but the page never heard the episode end")
        elif view.state == "ended":
            raise ConnectionError(f"the session ended ({view.ended_reason}) without a code")
        if time.monotonic() - started > timeout_s:
            raise TimeoutError(f"no completion code after {timeout_s:.0f} s")
        await asyncio.sleep(0.25)


async def visit(http: aiohttp.ClientSession, settings: CrowdSettings, index: int) -> WorkerReport:
    """One bot's whole visit; a failure is reported in `error`, never raised."""
    name = f"bot-{index:03d}"
    report = WorkerReport(name=name)
    if settings.skills:
        report.skill = settings.skills[index % len(settings.skills)]
    if settings.faults:
        report.fault = settings.faults[index % len(settings.faults)]
    api = WorkerApi(http, settings.coordinator_url, settings.campaign)
    joined_at = time.monotonic()
    try:
        params = {"PROLIFIC_PID": name, "STUDY_ID": settings.study_id, "SESSION_ID": f"{name}-1"}
        await api.join(params)
        await api.start_session()
        report.session_id = api.session_id
        await _drive(api, report, settings, index, joined_at)
    except Exception as exc:  # one bot's failure is its report, not the crowd's
        report.error = f"{type(exc).__name__}: {exc}"
    finally:
        await api.leave()
    return report


async def run_crowd(
    settings: CrowdSettings, count: int, stagger_s: float = 0.5
) -> list[WorkerReport]:
    """`count` bots joining `stagger_s` apart, all at once after that."""
    async with aiohttp.ClientSession() as http:

        async def staggered(index: int) -> WorkerReport:
            await asyncio.sleep(index * stagger_s)
            return await visit(http, settings, index)

        return list(await asyncio.gather(*(staggered(i) for i in range(count))))
