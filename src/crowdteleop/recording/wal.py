"""Crash-safe episode recording: a write-ahead log while the episode runs, one HDF5 file after.

Write-ahead log (``<episode_id>.wal``): the magic ``CTWAL02\\n``, then records framed
as ``<u32 payload length><u32 CRC-32 of payload><payload>`` (little-endian). The first payload
is the header (``H`` + JSON: episode id, creation time, metadata with the MJCF); every other one a
step (``C`` + index, times, reward, success, state and action sizes, flags, the device
command's numbers, contact count; the raw float64 bytes of state and action; contact
intensities and names; the step's subtask labels, if it has them; JSON only of a command or
contacts that do not fit that layout; see ``wal_codec``). Version 1 logs (``CTWAL01\\n``, steps
as ``S`` records with the command and contacts in JSON) are still read. Binary rather than JSON
lines because (1) states and actions are stored as their IEEE bits, so replay is exact by
construction (-0.0, subnormals and all); (2) the checksum tells a torn or garbage tail (a kill
mid-write, or the zero-filled block a power loss can leave) from a record, where a damaged JSON
number could still parse; (3) it is cheap on the control loop, which only validates a step's
numbers and keeps it: packing, framing and checksums happen when the buffer is flushed, by a
flusher thread once ``flush_interval_s`` has passed (so neither they nor the fsync stall the
control loop): a crash loses at most that.

A live recorder holds ``flock`` on its log, so ``recover_orphans`` (``wal_recovery``) never
touches an episode that is still being recorded, and the lock dies with a killed process.
``wal_reader`` reads a log back. The finished episode
(``<episode_id>.hdf5``) is laid out as one robomimic demo (``data/demo_0``); see
``docs/recording.md``. It is written under a temporary name and renamed, then the log is
removed: a crash at any point leaves either the log or the finished file (or both, which
recovery resolves in favour of the finished file).
"""

from __future__ import annotations

import dataclasses
import fcntl
import logging
import math
import os
import re
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from crowdteleop.errors import InvalidActionError, InvalidStateError
from crowdteleop.recording.episode_file import (
    EPISODE_SUFFIX,
    InvalidRecordError,
    RecordingError,
    StepLabels,
    StepRecord,
    split_metadata,
    to_json,
    write_episode,
)
from crowdteleop.recording.storage import fsync_directory
from crowdteleop.recording.wal_codec import WAL_MAGIC, WAL_SUFFIX, encode_steps, frame
from crowdteleop.recording.wal_reader import read_partial
from crowdteleop.vocab import OUTCOMES, Outcome

log = logging.getLogger(__name__)


_F8 = np.dtype("<f8")
_EPISODE_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}")


class EpisodeRecorder:
    """Records one episode: ``append`` every control step, then ``finalize`` with the outcome.

    Safe to call from several threads (one lock, held by ``append`` for the time of one step's
    validation; packing and the fsync happen outside it).
    """

    def __init__(
        self,
        directory: Path,
        episode_id: str,
        metadata: dict[str, Any],
        flush_interval_s: float = 1.0,
    ) -> None:
        if not isinstance(episode_id, str) or not _EPISODE_ID.fullmatch(episode_id):
            raise InvalidRecordError(
                f"episode id {episode_id!r} must be 1-128 letters, digits, '.', '_' or '-', "
                "starting with a letter or digit (it names files)"
            )
        if not flush_interval_s >= 0:
            raise InvalidRecordError(f"flush_interval_s must be >= 0, got {flush_interval_s}")
        split_metadata(metadata)  # validates model_xml and env_args
        self.directory = Path(directory)
        self.episode_id = episode_id
        self.flush_interval_s = float(flush_interval_s)
        self.wal_path = self.directory / f"{episode_id}{WAL_SUFFIX}"
        self.episode_path = self.directory / f"{episode_id}{EPISODE_SUFFIX}"
        header = {"episode_id": episode_id, "created_at": time.time(), "metadata": metadata}
        header_payload = b"H" + to_json(header, "metadata").encode()
        self.directory.mkdir(parents=True, exist_ok=True)
        if self.episode_path.exists():
            raise RecordingError(f"episode {episode_id} is already recorded: {self.episode_path}")
        self._fd = _create_wal(self.wal_path, WAL_MAGIC + frame(header_payload))
        self._lock = threading.Lock()  # state and buffer; held briefly by append
        self._io = threading.Lock()  # writes to the log; always taken before _lock
        self._due = threading.Event()
        self._flusher: threading.Thread | None = None
        self._deferred: RecordingError | None = None  # a background flush's failure
        self._buffer = bytearray()  # framed records not yet durable
        self._entries: list[StepRecord] = []  # validated steps, packed by the next flush
        self._notes = 0  # commands or contact lists stored as a note (JSON refused them)
        self._durable_size = os.fstat(self._fd).st_size
        self._last_flush = time.monotonic()
        self._steps = 0
        self._flushed_steps = 0
        self._sizes: tuple[int, int] | None = None  # state and action sizes, from step 0
        self._shapes: tuple[tuple[int], tuple[int]] | None = None  # the same as array shapes
        # zeros of the state's and the action's size: x.dot(zeros) is NaN unless x is finite
        self._zeros = np.zeros(0), np.zeros(0)
        self._closed = False

    @property
    def steps(self) -> int:
        """Steps appended (buffered or durable)."""
        return self._steps

    @property
    def flushed_steps(self) -> int:
        """Steps fsync'd to the log: what survives a crash now."""
        return self._flushed_steps

    @property
    def notes(self) -> int:
        """Commands or contact lists stored as a note naming the problem, as JSON refused them
        (NaN, objects), and label parts stored as NaN / "" (a pose with NaN, a name that is not
        NUL-free UTF-8): the step itself is recorded."""
        return self._notes

    @property
    def closed(self) -> bool:
        return self._closed

    def append(self, record: StepRecord) -> None:
        """Buffer one step; write and fsync the buffer when ``flush_interval_s`` has passed.

        With ``flush_interval_s`` > 0 the write and fsync run in a background thread, so the
        control loop pays for the append alone (``flushed_steps`` grows once the fsync is
        done); with 0 every append is durable before it returns.

        A bad record (index, state, action, times, reward) raises before anything is buffered,
        so what was recorded stays intact. The recorder keeps the record's arrays and dicts
        until they are flushed: do not change them after appending. A command or contact list
        JSON cannot store is recorded as a note (``notes`` counts them).
        ``RecordingError`` means the step was buffered but a flush failed (a full disk): the
        log was cut back to whole records and the next flush retries.
        """
        with self._lock:
            if self._closed:
                self._check_open()
            self._entries.append(self._check(record))
            self._steps += 1
            deferred, self._deferred = self._deferred, None
            due = time.monotonic() - self._last_flush >= self.flush_interval_s
            if due and self.flush_interval_s == 0:
                self._flush_locked()
            elif due:
                self._last_flush = time.monotonic()
                self._start_flusher_locked()
                self._due.set()
        if deferred is not None:
            raise deferred

    def flush(self) -> None:
        """Write and fsync every buffered step now."""
        with self._io, self._lock:
            self._check_open()
            self._flush_locked()

    def finalize(self, outcome: Outcome, extra_metadata: dict[str, Any] | None = None) -> Path:
        """Flush, write the episode file from the log, remove the log; returns the file's path.

        If writing the file fails the log stays, so finalize can be retried (or the episode
        recovered after a crash); the recorder closes only once the file is in place.
        """
        if outcome not in OUTCOMES:
            raise InvalidRecordError(f"outcome {outcome!r} is not one of {', '.join(OUTCOMES)}")
        extra = dict(extra_metadata or {})
        to_json(extra, "extra_metadata")
        split_metadata(extra)
        with self._io, self._lock:
            self._check_open()
            self._flush_locked()
            partial = read_partial(self.wal_path)
            if partial.steps != self._steps or partial.ignored_tail_bytes:
                raise RecordingError(
                    f"{self.wal_path} holds {partial.steps} steps, {self._steps} were appended"
                )
            path = write_episode(self.episode_path, partial, outcome, extra, recovered=False)
            self.wal_path.unlink()
            fsync_directory(self.directory)
            self._close_locked()
            return path

    def close(self) -> None:
        """Flush and release the log without finalizing: ``recover_orphans`` will finish it."""
        with self._io, self._lock:
            if not self._closed:
                try:
                    self._flush_locked()
                finally:
                    self._close_locked()

    def _check_open(self) -> None:
        if self._closed:
            raise RecordingError(f"episode {self.episode_id} is finalized or closed")

    def _start_flusher_locked(self) -> None:
        if self._flusher is None:
            self._flusher = threading.Thread(
                target=self._flush_when_due, name=f"wal-{self.episode_id}", daemon=True
            )
            self._flusher.start()

    def _flush_when_due(self) -> None:
        """The background flusher: the fsync happens outside ``_lock``, appends go on."""
        while True:
            self._due.wait()
            self._due.clear()
            with self._io:
                with self._lock:
                    if self._closed:
                        return
                    pending, steps = bytes(self._buffer), self._steps
                    self._buffer.clear()
                    entries, self._entries = self._entries, []
                pending += self._pack(entries)  # outside _lock: appends go on meanwhile
                if not pending:
                    continue
                try:
                    self._write_durably(pending)
                except RecordingError as error:
                    with self._lock:
                        self._buffer[:0] = pending  # retried by the next flush
                        self._deferred = error
                    continue
                self._flushed_steps = steps

    def _flush_locked(self) -> None:
        """Write and fsync the buffer with ``_io`` and ``_lock`` held."""
        self._last_flush = time.monotonic()
        if self._entries:
            self._buffer += self._pack(self._entries)
            self._entries = []
        if not self._buffer:
            return
        self._write_durably(bytes(self._buffer))
        self._buffer.clear()
        self._flushed_steps = self._steps

    def _pack(self, entries: list[StepRecord]) -> bytes:
        """Framed records of validated steps, with ``_io`` held (so notes count once each)."""
        packed, notes = encode_steps(entries)
        self._notes += notes
        return packed

    def _write_durably(self, data: bytes) -> None:
        """Append ``data`` to the log and fsync it, with ``_io`` held."""
        try:
            pending = data
            while pending:
                pending = pending[os.write(self._fd, pending) :]
            os.fsync(self._fd)
        except OSError as error:
            # Cut what was half written so the log stays a sequence of whole records; the
            # buffer is kept and the next flush retries. If even that fails, stop: later
            # records behind a torn one would be unreadable, yet reported as flushed.
            try:
                os.ftruncate(self._fd, self._durable_size)
            except OSError:
                if not self._closed:
                    self._close_locked()
                raise RecordingError(
                    f"could not write {self.wal_path} ({error}) nor cut it back; recording "
                    f"stopped, its first {self._flushed_steps} steps are recoverable"
                ) from error
            raise RecordingError(f"could not write {self.wal_path}: {error}") from error
        self._durable_size += len(data)

    def _close_locked(self) -> None:
        os.close(self._fd)  # also releases the flock
        self._closed = True
        self._due.set()  # the flusher sees the recorder closed and ends

    def _check(self, record: StepRecord) -> StepRecord:
        """The step as it will be packed; raises, before anything is buffered, if it is bad.

        The hot path of the control loop, so only what decides whether the step is data: its
        index, state and action (flat, float64, finite, the episode's sizes: two dot products)
        and the scalars. No copy is made: the recorder owns the record's arrays and dicts from
        here on (``step_record`` builds fresh ones every step). Packing the device command and
        contacts, framing and checksums wait for the flush (the flusher thread's, normally).
        """
        index = record.index
        if index != self._steps:
            raise InvalidRecordError(
                f"step index {index} out of order: step {self._steps} comes next"
            )
        state, action = record.state, record.action
        try:
            if (state.shape, action.shape) != self._shapes:
                raise ValueError("first step, or other sizes")
            if state.dtype is not _F8 or action.dtype is not _F8:
                raise ValueError("not float64")
            zeros_s, zeros_a = self._zeros
            if not math.isfinite(state.dot(zeros_s) + action.dot(zeros_a)):
                raise ValueError("not finite")  # (checked again, in detail)
        except (AttributeError, TypeError, ValueError):
            state, action = self._checked_vectors(state, action)
            record = dataclasses.replace(record, state=state, action=action)
        try:
            total = float(record.server_time) + float(record.step_duration_s)
            total += float(record.reward)
        except (TypeError, ValueError):
            total = math.nan
        if not math.isfinite(total):
            _finite_scalar(record.server_time, "server_time")
            _finite_scalar(record.step_duration_s, "step_duration_s")
            _finite_scalar(record.reward, "reward")  # each finite: only their sum overflowed
        _check_extras(record)
        if self._sizes is None:  # the first step: nothing can fail from here on
            self._set_sizes(state.size, action.size)
        return record

    def _set_sizes(self, state_size: int, action_size: int) -> None:
        self._sizes = state_size, action_size
        self._shapes = (state_size,), (action_size,)
        self._zeros = np.zeros(state_size), np.zeros(action_size)

    def _checked_vectors(
        self, state: Any, action: Any
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """State and action validated one by one (the first step, or anything unusual)."""
        state = _finite_vector(state, "state", InvalidStateError)
        action = _finite_vector(action, "action", InvalidActionError)
        if self._sizes is not None and state.size != self._sizes[0]:
            raise InvalidStateError(
                f"state has {state.size} entries, earlier steps of this episode {self._sizes[0]}"
            )
        if self._sizes is not None and action.size != self._sizes[1]:
            raise InvalidActionError(
                f"action has {action.size} entries, earlier steps of this episode {self._sizes[1]}"
            )
        return state, action


def _create_wal(path: Path, head: bytes) -> int:
    """A locked, fsync'd log with its header, under its final name only once complete."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}-{threading.get_ident()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_APPEND | os.O_CLOEXEC, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.write(fd, head)
        os.fsync(fd)
        os.link(tmp, path)  # fails if the log exists: never two recorders on one episode
    except FileExistsError as error:
        os.close(fd)
        tmp.unlink(missing_ok=True)
        raise RecordingError(
            f"episode {path.stem} already has a write-ahead log: {path}"
        ) from error
    except BaseException:
        os.close(fd)
        tmp.unlink(missing_ok=True)
        raise
    tmp.unlink()
    fsync_directory(path.parent)
    return fd


def _finite_vector(value: Any, name: str, error: type[ValueError]) -> npt.NDArray[np.float64]:
    try:
        vector = np.asarray(value, dtype="<f8")
    except (TypeError, ValueError) as exc:
        raise error(f"{name} is not an array of floats: {exc}") from exc
    if vector.ndim != 1 or vector.size == 0:
        raise error(f"{name} must be a non-empty flat vector, got shape {vector.shape}")
    if not np.isfinite(vector).all():
        raise error(f"{name} contains NaN or infinity")
    return vector


_POSE_SHAPE = (7,)


def _check_extras(record: StepRecord) -> None:
    """The command, contacts and labels: their types (packing them waits for the flush)."""
    if not isinstance(record.command, dict) or not isinstance(record.contacts, list):
        raise InvalidRecordError("command must be a dict and contacts a list")
    if record.labels is not None:
        _check_labels(record.labels)


def _check_labels(labels: StepLabels) -> None:
    """Types and shapes only (a few microseconds): NaN poses and odd names are the packer's to
    store as NaN / "" and count, so labels never cost a step."""
    if type(labels) is not StepLabels:
        raise InvalidRecordError(f"labels must be a StepLabels, got {type(labels).__name__}")
    if type(labels.stage) is not str or type(labels.relative_to) is not str:
        raise InvalidRecordError("labels' stage and relative_to must be strings")
    if not isinstance(labels.object_poses, dict):
        raise InvalidRecordError("labels' object_poses must be a dict of name -> (7,) pose")
    for name, pose in (("hand", labels.hand_pose), *labels.object_poses.items()):
        if type(name) is not str or type(pose) is not np.ndarray or pose.shape != _POSE_SHAPE:
            raise InvalidRecordError(
                f"label pose {name!r} must be a (7,) float64 array (x y z qx qy qz qw), "
                f"got {getattr(pose, 'shape', type(pose).__name__)}"
            )
        if pose.dtype != _F8:
            raise InvalidRecordError(f"label pose {name!r} must be float64, got {pose.dtype}")


def _finite_scalar(value: Any, name: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError) as error:
        raise InvalidRecordError(f"{name} must be a number, got {value!r}") from error
    if not np.isfinite(number):
        raise InvalidRecordError(f"{name} is NaN or infinite")
    return number
