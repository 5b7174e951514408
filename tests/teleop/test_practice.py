"""The practice round before a worker's first demonstration, in a real session (real simulator,
real recorder), driven tick by tick as the control loop drives it."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from crowdteleop.teleop.broadcast import status_of
from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.teleop.practice import REACH_M, TARGET_OFFSET_M
from crowdteleop.teleop.protocol import PoseCommand
from crowdteleop.teleop.session import TeleopSession, TickResult

IDENTITY = (0.0, 0.0, 0.0, 1.0)


class Worker:
    """A keyboard on the session's board: one pose per control step, as a page sends them."""

    def __init__(self, session: TeleopSession) -> None:
        self.session, self.seq = session, 0
        self.last: TickResult | None = None

    async def hold(
        self, steps: int, position: tuple[float, float, float] = (0, 0, 0), engaged: bool = True
    ) -> TickResult | None:
        for _ in range(steps):
            self.seq += 1
            pose = PoseCommand(
                seq=self.seq,
                client_time_ms=1.0,
                device="keyboard",
                position=position,
                quaternion=IDENTITY,
                engaged=engaged,
                gripper=False,
            )
            self.session.board.apply_pose("page", pose)
            self.last = await self.session.tick(want_privileged=False)
        return self.last

    async def idle(self, steps: int) -> TickResult | None:
        return await self.hold(steps, engaged=False)


def recorded(tmp_path: Path) -> list[Path]:
    return [path for path in tmp_path.rglob("*") if path.is_file()]


@pytest.fixture
def session(tmp_path: Path) -> Iterator[TeleopSession]:
    config = TeleopConfig(recording={"directory": tmp_path / "episodes"}, practice_s=20)
    built = asyncio.run(TeleopSession.create(config))
    yield built
    asyncio.run(built.close())


def test_reaching_the_green_ball_ends_practice_and_nothing_is_recorded(session, tmp_path):
    async def scenario():
        worker = Worker(session)
        first = await worker.idle(1)
        start = first.end_effector.copy()
        status = status_of(session, first)
        assert (status.practice, status.practice_left_s, status.episode) == ("running", 20.0, 0)
        target = session.practice.target_m
        assert np.linalg.norm(target - start) == pytest.approx(0.123, abs=0.002)
        assert [m.position_m for m in session.practice.markers()] == [tuple(target)]

        seed = session.tracker.metadata.reset_seed
        await worker.hold(2)  # press the clutch: the device anchors at its origin
        for fraction in np.linspace(0.1, 1.0, 20):  # then move it by the ball's offset
            await worker.hold(1, tuple(fraction * np.array(TARGET_OFFSET_M)))
        near = None
        for _ in range(60):
            if session.practice.stage != "running":
                break
            hand = worker.last.end_effector if worker.last else start
            near = np.linalg.norm(hand - target)
            await worker.hold(1, TARGET_OFFSET_M)
        status = status_of(session, worker.last)
        assert (status.practice, status.practice_reached) == ("done", True), near
        assert session.tracker.metadata.reset_seed == seed + 1, "a fresh scene for episode 1"
        assert session.practice.markers() == ()
        assert np.linalg.norm(worker.last.end_effector - start) < REACH_M, "the hand is back"
        assert session.tracker.state == "ready" and session.tracker.number == 0
        assert session.pop_finished() == [] and recorded(tmp_path) == []

        await worker.idle(1)  # the reset let go of the clutch: the next press starts episode 1
        await worker.hold(3)
        assert (session.tracker.state, session.tracker.number) == ("running", 1)
        assert status_of(session, worker.last).practice == "done"

    asyncio.run(scenario())


def test_practice_counts_its_seconds_from_the_first_move_and_then_ends(tmp_path):
    async def scenario():
        config = TeleopConfig(recording={"directory": tmp_path / "episodes"}, practice_s=1.0)
        session = await TeleopSession.create(config)
        try:
            worker = Worker(session)
            await worker.idle(30)  # reading the instructions: the clock has not started
            assert session.practice.left_s == 1.0
            await worker.hold(10)  # a keypress, holding still: half the round
            assert session.practice.left_s == pytest.approx(0.5)
            await worker.hold(9)
            assert session.practice.running
            seed = session.tracker.metadata.reset_seed
            await worker.hold(1)
            assert (session.practice.stage, session.practice.reached) == ("done", False)
            assert session.tracker.metadata.reset_seed == seed + 1
            assert session.tracker.number == 0 and recorded(tmp_path) == []
        finally:
            await session.close()

    asyncio.run(scenario())


def test_skip_ends_practice_and_the_first_episode_is_number_one(session, tmp_path):
    async def scenario():
        worker = Worker(session)
        await worker.hold(40, (0.0, 0.05, 0.0))  # moving, but no episode while practising
        assert session.tracker.number == 0 and session.practice.running
        seed = session.tracker.metadata.reset_seed
        session.request_skip_practice()
        await worker.hold(1, (0.0, 0.05, 0.0))
        assert session.practice.stage == "done" and not session.practice.reached
        assert session.tracker.metadata.reset_seed == seed + 1
        await worker.idle(1)
        await worker.hold(5)
        assert (session.tracker.state, session.tracker.number) == ("running", 1)
        session.request_reset()
        await worker.idle(1)
        assert [f.number for f in session.pop_finished()] == [1]
        assert session.practice.stage == "done", "a reset is no new worker: no practice again"

    asyncio.run(scenario())
    files = [path.name for path in recorded(tmp_path)]
    assert len(files) == 1 and "practice" not in files[0]  # episode 1's log only


def test_practice_happens_once_per_worker_assignment(session, tmp_path):
    async def scenario():
        worker = Worker(session)
        session.request_skip_practice()
        await worker.idle(1)
        assert session.practice.stage == "done"
        session.request_skip_practice()  # skipping twice does nothing more
        seed = session.tracker.metadata.reset_seed
        await worker.idle(1)
        assert session.tracker.metadata.reset_seed == seed

        # A warm spare handed to a new worker: the new worker practises.
        new_worker = session.config.model_copy(update={"worker_id": "w2", "practice_s": 20.0})
        session.assign(new_worker)
        await worker.idle(1)
        assert session.practice.running and session.practice.left_s == 20.0
        # ... unless their campaign has no practice round.
        session.assign(session.config.model_copy(update={"worker_id": "w3", "practice_s": 0.0}))
        await worker.idle(1)
        await worker.hold(3)
        assert session.practice.stage == "off"
        assert (session.tracker.state, session.tracker.number) == ("running", 1)

    asyncio.run(scenario())


def test_without_a_practice_round_the_first_move_starts_episode_one(tmp_path):
    async def scenario():
        session = await TeleopSession.create(
            TeleopConfig(recording={"directory": tmp_path / "episodes"})
        )
        try:
            result = await Worker(session).hold(3)
            status = status_of(session, result)
            assert (status.practice, status.episode, status.state) == ("off", 1, "running")
            assert session.practice.markers() == ()
        finally:
            await session.close()

    asyncio.run(scenario())
