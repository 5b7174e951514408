"""When an episode starts and ends, and what becomes of its recording."""

from __future__ import annotations

import logging
import uuid
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from crowdteleop.data.recording import EpisodeRecorder, StepRecord
from crowdteleop.data.storage import EpisodeStorage

log = logging.getLogger(__name__)

Outcome = Literal["success", "reset", "timeout", "disconnect", "crash"]
SessionState = Literal["ready", "running", "stopped"]


@dataclass(frozen=True)
class FinishedEpisode:
    number: int
    episode_id: str
    outcome: Outcome
    steps: int
    recorder: EpisodeRecorder | None


@dataclass
class EpisodeTracker:
    """The episode state machine of a session.

    ready -> running on the first engaged command after a reset; running ends on success held
    for `success_hold_steps`, reset, stop, time limit or the controlling device leaving.
    `stopped` pauses the simulation until `start`.
    """

    control_dt: float
    time_limit_s: float
    success_hold_steps: int
    recordings: Path
    metadata: dict[str, Any]
    flush_interval_s: float = 1.0
    state: SessionState = "ready"
    number: int = 0
    steps: int = 0
    successes: int = 0
    _held: int = 0
    _recorder: EpisodeRecorder | None = field(default=None, repr=False)
    _episode_id: str = ""

    @property
    def elapsed_s(self) -> float:
        return self.steps * self.control_dt

    @property
    def recording(self) -> bool:
        return self.state == "running"

    def maybe_start(self, engaged: bool) -> bool:
        """Start an episode if the session is ready and the clutch is held."""
        if self.state != "ready" or not engaged:
            return False
        self.number += 1
        self.steps = 0
        self._held = 0
        self._episode_id = f"{self.metadata.get('session_id', 'session')}-{uuid.uuid4().hex[:12]}"
        self._recorder = EpisodeRecorder(
            self.recordings,
            self._episode_id,
            {**self.metadata, "episode": self.number},
            flush_interval_s=self.flush_interval_s,
        )
        self.state = "running"
        return True

    def record(self, record: StepRecord) -> Outcome | None:
        """Append one step; returns the outcome if this step ended the episode."""
        assert self._recorder is not None
        self._recorder.append(record)
        self.steps += 1
        self._held = self._held + 1 if record.success else 0
        if self._held >= self.success_hold_steps:
            return "success"
        if self.elapsed_s >= self.time_limit_s:
            return "timeout"
        return None

    def end(self, outcome: Outcome, stop: bool = False) -> FinishedEpisode | None:
        """Close the running episode (if any); the recorder is finalized by the caller, off
        the control loop. The session then waits for the next engaged command."""
        finished = None
        if self.state == "running":
            if outcome == "success":
                self.successes += 1
            finished = FinishedEpisode(
                self.number, self._episode_id, outcome, self.steps, self._recorder
            )
        self._recorder = None
        self.state = "stopped" if stop else "ready"
        return finished


def store_episode(
    finished: FinishedEpisode,
    storage: EpisodeStorage,
    keep_failed: bool,
    extra_metadata: dict[str, Any],
) -> str | None:
    """Finalize the recording and hand it to storage; returns its URI (None if discarded).

    Runs in a worker thread: writing the HDF5 file must not stall the control loop.
    """
    if finished.recorder is None:
        return None
    path = finished.recorder.finalize(finished.outcome, extra_metadata)
    if finished.outcome != "success" and not keep_failed:
        path.unlink(missing_ok=True)
        return None
    folder = "success" if finished.outcome == "success" else "other"
    uri = storage.put(path, f"{folder}/{path.name}")
    path.unlink(missing_ok=True)  # storage holds its own copy now
    log.info(
        "episode %s (%s, %d steps) stored at %s",
        finished.episode_id,
        finished.outcome,
        finished.steps,
        uri,
    )
    return uri
