"""When an episode starts and ends, and what becomes of its recording."""

from __future__ import annotations

import logging
import uuid
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
from pydantic import ValidationError

from crowdteleop.control.teleoperator import TeleopStep
from crowdteleop.recording.episode_file import (
    CommandRecord,
    StepLabels,
    StepRecord,
    read_metadata,
)
from crowdteleop.recording.metadata import EpisodeMetadata
from crowdteleop.recording.quality import EpisodeMetrics
from crowdteleop.recording.storage import EpisodeStorage
from crowdteleop.recording.stores import SavedWhen
from crowdteleop.recording.versions import runtime_versions
from crowdteleop.recording.wal import EpisodeRecorder
from crowdteleop.vocab import DeviceKind, Outcome

log = logging.getLogger(__name__)

SessionState = Literal["ready", "running", "stopped"]


@dataclass(frozen=True)
class FinishedEpisode:
    number: int
    episode_id: str
    outcome: Outcome
    steps: int
    recorder: EpisodeRecorder | None
    device: DeviceKind | None = None  # the device driving when the episode started
    resets_before: int = 0  # episodes reset or failed in the session since its last success


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
    metadata: EpisodeMetadata
    flush_interval_s: float = 1.0
    state: SessionState = "ready"
    number: int = 0
    steps: int = 0
    successes: int = 0
    since_success: int = 0  # episodes that ended otherwise since the last success
    _held: int = 0
    _recorder: EpisodeRecorder | None = field(default=None, repr=False)
    _episode_id: str = ""
    _device: DeviceKind | None = None

    @property
    def elapsed_s(self) -> float:
        return self.steps * self.control_dt

    @property
    def recording(self) -> bool:
        return self.state == "running"

    def maybe_start(
        self,
        engaged: bool,
        device: DeviceKind | None = None,
        controller_state: Sequence[float] = (),
    ) -> bool:
        """Start an episode if the session is ready and the clutch is held; the simulation's
        controller state at that moment goes into the episode's metadata."""
        if self.state != "ready" or not engaged:
            return False
        self._device = device
        self.number += 1
        self.steps = 0
        self._held = 0
        session = self.metadata.session_id or "session"
        self._episode_id = f"{session}-{uuid.uuid4().hex[:12]}"
        self._recorder = EpisodeRecorder(
            self.recordings,
            self._episode_id,
            self.metadata.model_copy(
                update={
                    "episode": self.number,
                    "controller_state_at_start": [float(v) for v in controller_state],
                }
            ).to_record(),
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
            finished = FinishedEpisode(
                self.number,
                self._episode_id,
                outcome,
                self.steps,
                self._recorder,
                self._device,
                resets_before=self.since_success,
            )
            if outcome == "success":
                self.successes += 1
                self.since_success = 0
            else:
                self.since_success += 1
        self._recorder = None
        self.state = "stopped" if stop else "ready"
        return finished


def step_record(
    index: int,
    state: npt.NDArray[np.float64],
    step: TeleopStep,
    raw_command: CommandRecord,
    server_time: float,
    duration_s: float,
    labels: StepLabels | None = None,
) -> StepRecord:
    """What the recorder stores of one control step (the recorder validates and copies);
    ``labels`` describe ``state``, as ``StepLabels.read`` reads them before the step."""
    result = step.result
    return StepRecord(
        index=index,
        state=state,
        action=step.action,
        command=raw_command,
        server_time=server_time,
        step_duration_s=duration_s,
        reward=result.reward,
        success=result.success,
        contacts=list(map(vars, result.contacts)),
        labels=labels,
    )


@dataclass(frozen=True)
class StoredEpisode:
    uri: str
    metrics: EpisodeMetrics | None  # None: the recording could not be measured


def store_episode(
    finished: FinishedEpisode,
    storage: EpisodeStorage,
    keep_failed: bool,
    extra_metadata: dict[str, Any],
    saved_when: SavedWhen = "stored",
    store_wait_s: float = 30.0,
) -> StoredEpisode | None:
    """Finalize the recording (measuring its quality) and hand it to storage; returns its URI
    and metrics once it is durable (None if discarded). The server tells the worker "saved"
    only after this returns.

    Durable means: a local store fsync'd the file; an S3 store behind a spool confirmed the
    upload (size, MD5 and SHA-256 checked) within ``store_wait_s``, or, with
    ``saved_when="spooled"``, the spool holds a fsync'd copy. When the store does not confirm
    in time this raises ``StorageUnavailableError``: the episode stays spooled and is uploaded
    when the store returns, but the worker is not told it was saved.

    Runs in a worker thread: writing the HDF5 file must not stall the control loop.
    """
    if finished.recorder is None:
        return None
    extra = {
        "versions": runtime_versions(),
        "resets_before": finished.resets_before,
        **extra_metadata,
    }
    path = finished.recorder.finalize(finished.outcome, extra)
    if finished.outcome != "success" and not keep_failed:
        path.unlink(missing_ok=True)
        return None
    metrics = _metrics(path)
    folder = "success" if finished.outcome == "success" else "other"
    key = f"{folder}/{path.name}"
    uri = storage.put(path, key)
    path.unlink(missing_ok=True)  # storage (or its spool) holds its own fsync'd copy now
    if saved_when == "stored":
        storage.wait_durable(key, store_wait_s)
    log.info(
        "episode %s (%s, %d steps) stored at %s",
        finished.episode_id,
        finished.outcome,
        finished.steps,
        uri,
    )
    return StoredEpisode(uri, metrics)


def _metrics(path: Path) -> EpisodeMetrics | None:
    """What the episode file says of its quality (written with it by `write_episode`)."""
    quality = read_metadata(path).get("quality")
    try:
        return EpisodeMetrics.model_validate(quality)
    except ValidationError:
        log.warning("episode file %s carries no quality metrics: %s", path.name, quality)
        return None
