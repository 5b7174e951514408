"""One worker's session: the simulated robot, stepped on a fixed clock, off the event loop.

The session knows nothing of WebRTC: each tick it takes the controlling device's latest
command, steps and renders in its own simulation thread (the GL context lives there), records,
and returns what the peers should see. `crowdteleop.teleop.server` moves that over the network.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, TypeVar, TypeVarTuple, assert_never

import numpy as np
import numpy.typing as npt
from av import VideoFrame

from crowdteleop.control.command import DeviceCommand
from crowdteleop.control.teleoperator import Teleoperator
from crowdteleop.recording.episode_file import CommandRecord, RecordingError, StepLabels
from crowdteleop.recording.metadata import episode_metadata, simulation_facts
from crowdteleop.recording.storage import EpisodeStorage, disk_is_full
from crowdteleop.sim.factory import make_simulation
from crowdteleop.sim.interface import Simulation
from crowdteleop.sim.types import ContactEvent, Pose, TaskProgress
from crowdteleop.tasks import get_task
from crowdteleop.teleop.commands import CommandBoard
from crowdteleop.teleop.config import TeleopConfig
from crowdteleop.teleop.episode import (
    EpisodeTracker,
    FinishedEpisode,
    StoredEpisode,
    step_record,
    store_episode,
)
from crowdteleop.teleop.practice import PracticeRound
from crowdteleop.teleop.video import YuvConverter
from crowdteleop.vocab import Outcome

log = logging.getLogger(__name__)

HAPTIC_REPEAT_S = 0.25  # while a contact lasts, buzz again this often

R = TypeVar("R")
Args = TypeVarTuple("Args")


@dataclass(frozen=True)
class ResetScene:
    """End the running episode as ``reset`` and start a fresh scene."""


@dataclass(frozen=True)
class StopSession:
    """End the running episode as ``reset`` and pause until `StartSession`."""


@dataclass(frozen=True)
class StartSession:
    """Resume a stopped session with a fresh scene."""


@dataclass(frozen=True)
class SkipPractice:
    """End the practice round (if one runs); the scene resets for episode 1."""


@dataclass(frozen=True)
class EndEpisode:
    """End the running episode with `outcome` (its driver left); the scene resets."""

    outcome: Outcome


SessionRequest = ResetScene | StopSession | StartSession | SkipPractice | EndEpisode
"""What peers may ask of the session between two steps (the tracker never changes in one)."""


@dataclass(frozen=True)
class TickResult:
    """What one control step produced, for the peers."""

    image: npt.NDArray[np.uint8]
    image_changed: bool
    command_seq: int
    success: bool
    progress: TaskProgress | None
    end_effector: npt.NDArray[np.float64]
    haptics: list[ContactEvent]
    privileged: dict[str, Any] | None = None
    step_index: int = 0
    video_frame: VideoFrame | None = None  # the image as the encoder takes it, when it changed


@dataclass
class _HapticFilter:
    """Buzz on contact onset, then every HAPTIC_REPEAT_S while it lasts: a phone's vibration
    motor cannot follow 20 Hz events and a steady stream would feel like noise."""

    last_sent: dict[tuple[str, str], float] = field(default_factory=dict)

    def select(self, contacts: list[ContactEvent], now: float) -> list[ContactEvent]:
        current = {(c.robot_part, c.object): c for c in contacts}
        chosen = []
        for key, contact in current.items():
            if now - self.last_sent.get(key, -1e9) >= HAPTIC_REPEAT_S:
                self.last_sent[key] = now
                chosen.append(contact)
        for key in list(self.last_sent):
            if key not in current:
                del self.last_sent[key]
        return chosen


class TeleopSession:
    """Build with `await TeleopSession.create(config)`; drive with `tick`."""

    def __init__(self, config: TeleopConfig, executor: ThreadPoolExecutor) -> None:
        self.config = config
        self.board = CommandBoard()
        self.storage: EpisodeStorage = config.recording.open_storage()
        self.task = get_task(config.sim.task)
        self._executor = executor
        self._haptics = _HapticFilter()
        self._yuv = YuvConverter()
        self._seed = config.seed
        self._last_image: npt.NDArray[np.uint8] | None = None
        self._pending: list[SessionRequest] = []
        self._finished: list[FinishedEpisode] = []
        self.sim_errors = 0
        # Why episodes cannot be recorded now (a full disk...): nothing moves until they can.
        self.recording_failure: str | None = None
        self.teleop: Teleoperator  # set in _build (sim thread)
        self.tracker: EpisodeTracker
        self.practice: PracticeRound  # the worker's practice round (`teleop/practice.py`)

    @classmethod
    async def create(cls, config: TeleopConfig) -> TeleopSession:
        executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sim")
        session = cls(config, executor)
        await session._in_sim_thread(session._build)
        return session

    async def _in_sim_thread(self, function: Callable[[*Args], R], *args: *Args) -> R:
        return await asyncio.get_running_loop().run_in_executor(self._executor, function, *args)

    def _build(self) -> None:
        sim = make_simulation(self.config.sim)
        self.teleop = Teleoperator(sim, self.config.control)
        self.teleop.reset(self._seed)
        metadata = episode_metadata(
            self.config.sim,
            self.config.control,
            camera=self.config.video.camera,
            model_xml=sim.mjcf_xml(),
            reset_seed=self._seed,
            session_id=self.config.session_id,
            worker_id=self.config.worker_id,
            region=self.config.region,
        ).model_copy(update=simulation_facts(sim))
        self.tracker = EpisodeTracker(
            control_dt=sim.control_dt,
            time_limit_s=self.config.episode_time_limit_s,
            success_hold_steps=self.config.success_hold_steps,
            recordings=self.config.recording.directory / "incoming",
            metadata=metadata,
            flush_interval_s=self.config.recording.flush_interval_s,
        )
        self.practice = PracticeRound.for_worker(self.config.practice_s, sim.control_dt)

    def assign(self, config: TeleopConfig) -> None:
        """Take a session's identity (a warm spare being handed to a worker): recordings from
        now on carry the new ids and go to the new directory."""
        self.config = config
        self.storage.close()  # a spooled S3 store stops its upload thread
        self.storage = config.recording.open_storage()
        self.tracker.metadata = self.tracker.metadata.model_copy(
            update={
                "session_id": config.session_id,
                "worker_id": config.worker_id,
                "region": config.region,
            }
        )
        self.tracker.recordings = config.recording.directory / "incoming"
        # A new worker practises (a spare is assigned once and nobody drove it before).
        self.practice = PracticeRound.for_worker(config.practice_s, self.tracker.control_dt)

    @property
    def control_hz(self) -> float:
        return self.config.sim.control_hz

    # --- requests from peers (event loop) -------------------------------------------------
    # They only leave a note: the tracker changes between steps, never during one.

    def request_reset(self) -> None:
        self._pending.append(ResetScene())

    def request_stop(self) -> None:
        self._pending.append(StopSession())

    def request_start(self) -> None:
        self._pending.append(StartSession())

    def request_skip_practice(self) -> None:
        self._pending.append(SkipPractice())

    def request_end(self, outcome: Outcome) -> None:
        """End the running episode (the controlling device left); the scene resets."""
        self._pending.append(EndEpisode(outcome))

    def pop_finished(self) -> list[FinishedEpisode]:
        finished, self._finished = self._finished, []
        return finished

    def _end(self, outcome: Outcome, stop: bool = False) -> None:
        finished = self.tracker.end(outcome, stop=stop)
        if finished is not None:
            self._finished.append(finished)

    async def _apply_requests(self) -> None:
        needs_reset = False
        for request in self._pending:
            needs_reset = self._apply_request(request) or needs_reset
        self._pending.clear()
        if needs_reset:
            await self._in_sim_thread(self._reset_scene)

    def _apply_request(self, request: SessionRequest) -> bool:
        """Apply one request between steps; returns whether the scene must reset."""
        state = self.tracker.state
        match request:
            case StopSession():
                self._end("reset", stop=True)
                return False
            case StartSession() if state == "stopped":
                self.tracker.state = "ready"
                return True
            case ResetScene() if state != "stopped":
                self._end("reset")
                return True
            case EndEpisode(outcome) if state == "running":
                self._end(outcome)
                return True
            case SkipPractice():
                return self.practice.skip()
            case StartSession() | ResetScene() | EndEpisode():
                return False  # nothing to do in this state
            case _:
                assert_never(request)

    # --- the control step ------------------------------------------------------------------

    async def tick(self, want_privileged: bool) -> TickResult | None:
        """One control step. None while stopped (nothing moves, nothing is rendered) or when
        the step failed (the episode ends as ``crash``; the next tick starts a fresh scene)."""
        await self._apply_requests()
        if self.tracker.state == "stopped":
            return None
        command = self.board.command()
        raw = self.board.raw_command()
        driver = self.board.driver
        try:
            if not self.practice.running:  # a practice round records nothing
                self.tracker.maybe_start(
                    command.engaged,
                    driver.device if driver else None,
                    self.teleop.sim.controller_state().tolist(),  # the sim thread is idle now
                )
        except (RecordingError, OSError) as error:  # the episode's log cannot be created
            self._recording_failed(error)
            return None
        if self.recording_failure is not None and self.tracker.state == "running":
            self.recording_failure = None  # a new episode's log was created: space again
        try:
            return await self._in_sim_thread(self._step, command, raw, want_privileged)
        except Exception as error:  # a simulation failure ends the episode; the session lives
            log.exception("simulation step failed")
            self.sim_errors += 1
            if isinstance(error, RecordingError | OSError):
                self._recording_failed(error)
            self._end("crash")
            self._pending.append(ResetScene())
            return None

    def _recording_failed(self, error: BaseException) -> None:
        self.recording_failure = "the server's disk is full" if disk_is_full(error) else str(error)

    def _step(
        self, command: DeviceCommand, raw: CommandRecord, want_privileged: bool
    ) -> TickResult:
        """Runs in the simulation thread."""
        sim = self.teleop.sim
        state = sim.get_state() if self.tracker.recording else None
        labels = StepLabels.read(sim) if state is not None else None  # of `state`, before the step
        started_wall, started = time.time(), time.perf_counter()
        step = self.teleop.step(command)
        duration = time.perf_counter() - started
        if state is not None:  # recording: the recorder validates, converts and copies
            outcome = self.tracker.record(
                step_record(self.tracker.steps, state, step, raw, started_wall, duration, labels)
            )
            if outcome is not None:
                self._end(outcome)
                self._reset_scene()
        hand = sim.robot_state().end_effector  # read once: status and privileged state share it
        if self.practice.advance(command.engaged, hand.position):  # it ended: a fresh scene
            self._reset_scene()
            hand = sim.robot_state().end_effector
        video = self.config.video
        image = sim.render(video.camera, video.width, video.height, self.practice.markers())
        changed = self._last_image is None or image is not self._last_image
        if changed and self._last_image is not None and image.shape == self._last_image.shape:
            changed = not np.array_equal(image, self._last_image)
        self._last_image = image
        privileged = {**_privileged(sim, hand), "scene": self._seed} if want_privileged else None
        return TickResult(
            image=image,
            image_changed=changed,
            video_frame=self._yuv.convert(image) if changed else None,
            command_seq=command.seq,
            success=step.result.success,
            progress=step.result.progress,
            end_effector=hand.position.copy(),
            haptics=self._haptics.select(step.result.contacts, time.monotonic()),
            privileged=privileged,
            step_index=self.tracker.steps,
        )

    def _reset_scene(self) -> None:
        """A fresh scene with the next seed (simulation thread). The seed goes into the next
        episode's metadata: osc episodes re-simulate exactly only from a reset with it."""
        self._seed += 1
        self.teleop.reset(self._seed)
        # robosuite places some bodies in the model (Door's door), so the model file follows
        update = {"reset_seed": self._seed, "model_xml": self.teleop.sim.mjcf_xml()}
        self.tracker.metadata = self.tracker.metadata.model_copy(update=update)
        self.board.release_clutch()
        self.practice.scene_reset()

    async def store(
        self, finished: FinishedEpisode, telemetry: dict[str, Any]
    ) -> StoredEpisode | None:
        """Finalize and store an episode's recording in a worker thread."""
        storage = self.config.recording.storage
        return await asyncio.to_thread(
            store_episode,
            finished,
            self.storage,
            self.config.recording.keep_failed,
            {**self.config.recording.labels, **telemetry},
            storage.saved_when,
            storage.store_wait_s,
        )

    async def close(self) -> None:
        """End a running episode as ``disconnect``, store it, free the simulation."""
        self._end("disconnect")
        for finished in self.pop_finished():
            await self.store(finished, {})
        await self._in_sim_thread(self.teleop.sim.close)
        self._executor.shutdown(wait=True)
        self.storage.close()  # a spooled S3 store stops its upload thread


def _privileged(sim: Simulation, hand: Pose) -> dict[str, Any]:
    def flat(pose: Pose) -> list[float]:
        return [*pose.position.tolist(), *pose.quaternion.tolist()]

    return {
        "end_effector": flat(hand),
        "objects": {name: flat(pose) for name, pose in sim.object_poses().items()},
    }
