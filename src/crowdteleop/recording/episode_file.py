"""One finished episode as one HDF5 file: a robomimic demo (``data/demo_0``) plus our extras.

Written under a temporary name, fsync'd and renamed, so a file under its final name is always
whole; ``read_episode`` reads it back and refuses foreign or damaged files with
``CorruptEpisodeError``. Layout: ``docs/recording.md``.
"""

from __future__ import annotations

import io
import json
import logging
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict
from urllib.parse import quote, unquote

import h5py
import numpy as np
import numpy.typing as npt

from crowdteleop.errors import CrowdteleopError
from crowdteleop.recording.quality import measure
from crowdteleop.recording.storage import fsync_directory
from crowdteleop.vocab import Outcome

log = logging.getLogger(__name__)
EPISODE_SUFFIX = ".hdf5"


class RecordingError(CrowdteleopError, RuntimeError):
    """The recorder cannot do what was asked: it is closed, or the disk refused a write."""


class InvalidRecordError(CrowdteleopError, ValueError):
    """A step, metadata or episode id that cannot be recorded as given (nothing was written)."""


class CorruptEpisodeError(CrowdteleopError, ValueError):
    """A file that is not, or no longer, a readable crowdteleop episode or write-ahead log."""


class CommandRecord(TypedDict, total=False):
    """The device command of one step as recorded: the driving device's latest state as sent.

    A plain dict at runtime; the recorder checks only that it is one and JSON-serializable, and
    a missing or odd field is stored as NaN / -1 / False / "" beside the raw JSON."""

    seq: int
    client_time_ms: float
    device: str | None
    position: list[float]
    quaternion: list[float]
    engaged: bool
    gripper: float | bool  # closed: a bool from a device, a float from the scripted rig


@dataclass(frozen=True, slots=True)
class StepLabels:
    """The subtask label of one control step, describing the state before its action.

    ``stage`` and ``relative_to`` are the task's `TaskProgress` (the stage the worker is in and
    the object its motion is relative to, "" when none); the poses are world-frame
    ``x y z qx qy qz qw`` (metres, unit quaternion): the hand (end effector) and every object
    ``Simulation.object_poses`` names. What MimicGen-style demonstration generation segments
    source demonstrations by. Build it with ``of`` from the simulation's own values."""

    stage: str
    relative_to: str
    hand_pose: npt.NDArray[np.float64]  # (7,): x y z qx qy qz qw, world frame, metres
    object_poses: dict[str, npt.NDArray[np.float64]]  # name -> (7,)

    @classmethod
    def of(cls, progress: Any, hand: Any, objects: Mapping[str, Any]) -> StepLabels:
        """From duck-typed sim values (progress.stage/.relative_to, pose.position/.quaternion)
        -- recording must not import sim."""
        return cls(
            str(progress.stage),
            str(getattr(progress, "relative_to", "")),
            _pose7(hand),
            {str(name): _pose7(pose) for name, pose in objects.items()},
        )

    @classmethod
    def read(cls, sim: Any) -> StepLabels:
        """The labels of a simulation's current state (a `crowdteleop.sim` Simulation, duck
        typed): the one way the teleop session, the scripted rig, ``dataset build`` and
        generation read them, before stepping, so a row's labels describe its state."""
        return cls.of(sim.progress(), sim.robot_state().end_effector, sim.object_poses())


def _pose7(pose: Any) -> npt.NDArray[np.float64]:
    row = np.empty(7)
    row[:3] = pose.position
    row[3:] = pose.quaternion
    return row


@dataclass(frozen=True)
class EpisodeLabels:
    """The subtask labels of an episode, one row per step (``StepLabels`` stacked).

    A step recorded without labels has stage and relative_to "" and NaN poses; an object
    missing at a step has a NaN row there."""

    stage: list[str]  # (N,) one per step
    relative_to: list[str]  # (N,)
    hand_pose: npt.NDArray[np.float64]  # (N, 7)
    object_poses: dict[str, npt.NDArray[np.float64]]  # name -> (N, 7)


def stack_labels(steps: list[StepLabels | None]) -> EpisodeLabels | None:
    """The episode's labels from its steps' (None if no step has any)."""
    if all(step is None for step in steps):
        return None
    n = len(steps)
    hand = np.full((n, 7), np.nan)
    objects: dict[str, npt.NDArray[np.float64]] = {}
    for t, step in enumerate(steps):
        if step is None:
            continue
        hand[t] = step.hand_pose
        for name, pose in step.object_poses.items():
            if name not in objects:
                objects[name] = np.full((n, 7), np.nan)
            objects[name][t] = pose
    return EpisodeLabels(
        stage=[step.stage if step is not None else "" for step in steps],
        relative_to=[step.relative_to if step is not None else "" for step in steps],
        hand_pose=hand,
        object_poses=objects,
    )


@dataclass(slots=True)  # not frozen: built every control step, and a frozen __init__ is slower
class StepRecord:
    """One control step as the teleop server saw it; ``state`` is the state before ``action``."""

    index: int
    state: npt.NDArray[np.float64]
    action: npt.NDArray[np.float64]
    command: CommandRecord
    server_time: float
    step_duration_s: float
    reward: float
    success: bool
    contacts: list[dict[str, Any]]
    labels: StepLabels | None = None  # the subtask label of ``state`` (None: not labelled)


@dataclass(frozen=True, kw_only=True)
class EpisodeData:
    """Arrays of one episode, one row per step; ``metadata`` excludes the MJCF and env args."""

    episode_id: str
    metadata: dict[str, Any]
    model_xml: str | None
    env_args: dict[str, Any] | None
    created_at: float
    states: npt.NDArray[np.float64]  # (N, S)
    actions: npt.NDArray[np.float64]  # (N, A)
    rewards: npt.NDArray[np.float64]  # (N,)
    success: npt.NDArray[np.bool_]  # (N,)
    server_time: npt.NDArray[np.float64]  # (N,)
    step_duration_s: npt.NDArray[np.float64]  # (N,)
    commands: list[CommandRecord]
    contacts: list[list[dict[str, Any]]]
    labels: EpisodeLabels | None = None  # None: recorded without subtask labels

    @property
    def steps(self) -> int:
        return len(self.rewards)


@dataclass(frozen=True, kw_only=True)
class PartialEpisode(EpisodeData):
    """What a write-ahead log holds; ``ignored_tail_bytes`` > 0 when its end was torn."""

    ignored_tail_bytes: int


@dataclass(frozen=True, kw_only=True)
class Episode(EpisodeData):
    """A finished episode file read back."""

    outcome: Outcome
    dones: npt.NDArray[np.uint8]  # (N,), robomimic's convention: 1 on success steps and the last
    finalized_at: float
    recovered: bool  # finalized by recover_orphans after a crash


def read_episode(path: Path) -> Episode:
    """A finished episode file read back (see ``docs/recording.md`` for the layout)."""
    return _read_episode(Path(path))


def split_metadata(
    metadata: dict[str, Any],
) -> tuple[dict[str, Any], str | None, dict[str, Any] | None]:
    """(metadata without them, model_xml, robomimic env_args with type=1 by default)."""
    if not isinstance(metadata, dict):
        raise InvalidRecordError(f"metadata must be a dict, got {type(metadata).__name__}")
    rest = dict(metadata)
    model_xml = rest.pop("model_xml", None)
    env_args = rest.pop("env_args", None)
    if model_xml is not None and not (isinstance(model_xml, str) and _is_utf8(model_xml)):
        raise InvalidRecordError("metadata model_xml must be the MJCF XML string")
    if env_args is not None:
        if not isinstance(env_args, dict) or not isinstance(env_args.get("env_name"), str):
            raise InvalidRecordError("metadata env_args must be a dict with an env_name string")
        env_args = {"env_name": env_args["env_name"], "type": 1, "env_kwargs": {}} | env_args
    return rest, model_xml, env_args


def to_json(value: Any, what: str) -> str:
    try:
        return json.dumps(value, allow_nan=False, separators=(",", ":"))
    except (TypeError, ValueError) as error:
        raise InvalidRecordError(f"{what} is not JSON-serializable without NaN: {error}") from error


# The finished episode file: one robomimic demo plus our extras (docs/recording.md).
FILE_FORMAT = "crowdteleop-episode"
FILE_FORMAT_VERSION = 1
DEMO = "data/demo_0"
_STR = h5py.string_dtype()


def write_episode(
    path: Path, partial: EpisodeData, outcome: str, extra: dict[str, Any], recovered: bool
) -> Path:
    """Write under a temporary name, fsync, rename: never a half file under the final name."""
    metadata, model_xml, env_args = split_metadata({**partial.metadata, **extra})
    metadata["quality"] = _quality(partial, metadata)
    model_xml = model_xml if model_xml is not None else partial.model_xml
    env_args = env_args if env_args is not None else partial.env_args
    # HDF5 builds the file in memory; only plain writes touch the disk. A full disk then is
    # an ordinary OSError (ENOSPC) here, never a failure inside HDF5's own I/O, which leaves
    # the library in a state that can take the process down later.
    image = io.BytesIO()
    _write_hdf5(image, partial, outcome, metadata, model_xml, env_args, recovered)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with open(tmp, "wb") as file:
            file.write(image.getbuffer())
            file.flush()
            os.fsync(file.fileno())
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    os.replace(tmp, path)
    fsync_directory(path.parent)
    return path


def _quality(partial: EpisodeData, metadata: dict[str, Any]) -> dict[str, Any]:
    """The episode's quality metrics (`recording/quality.py`); a failure to measure is logged
    and written down in their place, never a reason to lose the recording."""
    try:
        return measure(partial, metadata).model_dump(mode="json", exclude_none=True)
    except Exception as error:  # any bug in a metric must not cost the episode
        log.exception("measuring episode %s failed", partial.episode_id)
        return {"error": f"{type(error).__name__}: {error}"[:500]}


def read_metadata(path: Path) -> dict[str, Any]:
    """An episode file's metadata (its ids, telemetry, `quality`) without its arrays."""
    try:
        with h5py.File(path, "r") as file:
            return dict(json.loads(file.attrs["metadata"]))
    except (OSError, KeyError, ValueError) as error:
        raise CorruptEpisodeError(f"{path} has no readable episode metadata: {error}") from error


def _write_hdf5(
    image: io.BytesIO,
    partial: EpisodeData,
    outcome: str,
    metadata: dict[str, Any],
    model_xml: str | None,
    env_args: dict[str, Any] | None,
    recovered: bool,
) -> None:
    n = partial.steps
    dones = partial.success.astype(np.uint8)
    if n:
        dones[-1] = 1
    with h5py.File(image, "w") as file:
        file.attrs.update(
            format=FILE_FORMAT,
            format_version=FILE_FORMAT_VERSION,
            episode_id=partial.episode_id,
            outcome=outcome,
            metadata=to_json(metadata, "metadata"),
            created_at=partial.created_at,
            finalized_at=time.time(),
            recovered=recovered,
        )
        data = file.create_group("data")
        data.attrs["total"] = n
        if env_args is not None:
            file.attrs["env_args"] = data.attrs["env_args"] = to_json(env_args, "env_args")
        demo = file.create_group(DEMO)
        demo.attrs["num_samples"] = n
        if model_xml is not None:
            demo.attrs["model_file"] = model_xml
        for name in ("states", "actions", "rewards", "success", "server_time", "step_duration_s"):
            demo.create_dataset(name, data=getattr(partial, name))
        demo.create_dataset("dones", data=dones)
        demo.create_dataset(
            "contacts", data=[to_json(c, "contacts") for c in partial.contacts], dtype=_STR
        )
        commands = demo.create_group("commands")
        for name, column in _command_columns(partial.commands).items():
            commands.create_dataset(name, data=column, dtype=column.dtype)
        if partial.labels is not None:
            _write_labels(demo.create_group("labels"), partial.labels)


def _write_labels(group: h5py.Group, labels: EpisodeLabels) -> None:
    """``labels/``: stage, relative_to, hand_pose and ``object_poses/<name>``, the name
    percent-encoded (``object_dataset_name``) and kept as the dataset's ``name`` attribute."""
    group.create_dataset("stage", data=np.array(labels.stage, dtype=object), dtype=_STR)
    group.create_dataset("relative_to", data=np.array(labels.relative_to, dtype=object), dtype=_STR)
    group.create_dataset("hand_pose", data=labels.hand_pose.reshape(-1, 7))
    objects = group.create_group("object_poses", track_order=True)  # read back in order
    for name, poses in labels.object_poses.items():
        objects.create_dataset(object_dataset_name(name), data=poses).attrs["name"] = name


def object_dataset_name(name: str) -> str:
    """An object's dataset name under ``labels/object_poses``: URL percent-encoding of its UTF-8
    (``urllib.parse.quote(name, safe="")``: "Can/target" -> "Can%2Ftarget"; ``unquote`` reverses
    it). The WAL codec never packs "" or "." (names HDF5 cannot hold)."""
    return quote(name, safe="")


def _read_labels(demo: h5py.Group) -> EpisodeLabels | None:
    if "labels" not in demo:
        return None  # recorded before labels, or by a caller that gave none
    group = demo["labels"]
    objects = group["object_poses"]
    return EpisodeLabels(
        stage=list(group["stage"].asstr()[()]),
        relative_to=list(group["relative_to"].asstr()[()]),
        hand_pose=group["hand_pose"][()],
        object_poses={
            str(objects[key].attrs.get("name", unquote(key))): objects[key][()] for key in objects
        },
    )


def _command_columns(commands: list[CommandRecord]) -> dict[str, npt.NDArray[np.generic]]:
    """The device commands as columns; a field a command lacks is NaN / -1 / False / ""."""
    return {
        "seq": np.array([_int(c.get("seq")) for c in commands], dtype=np.int64),
        "client_time_ms": np.array([_floats(c.get("client_time_ms"), 1)[0] for c in commands]),
        "position": np.array([_floats(c.get("position"), 3) for c in commands]).reshape(-1, 3),
        "quaternion": np.array([_floats(c.get("quaternion"), 4) for c in commands]).reshape(-1, 4),
        "engaged": np.array([c.get("engaged") is True for c in commands], dtype=bool),
        "gripper": np.array([_floats(c.get("gripper"), 1)[0] for c in commands]),
        "device": np.array([_text(c.get("device")) for c in commands], dtype=_STR),
        "raw": np.array([to_json(c, "command") for c in commands], dtype=_STR),
    }


def _text(value: Any) -> str:
    """A string HDF5 stores as given (UTF-8, no NUL), else ""; the raw JSON keeps the rest."""
    return value if isinstance(value, str) and _is_utf8(value) and "\x00" not in value else ""


def _is_utf8(text: str) -> bool:
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _int(value: Any) -> int:
    integer = isinstance(value, int) and not isinstance(value, bool)
    return value if integer and -(2**63) <= value < 2**63 else -1  # raw keeps a larger one


def _floats(value: Any, n: int) -> npt.NDArray[np.float64]:
    try:
        array = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        return np.full(n, np.nan)
    return array if array.size == n else np.full(n, np.nan)


def _read_episode(path: Path) -> Episode:
    try:
        file = h5py.File(path, "r")
    except OSError as error:
        raise CorruptEpisodeError(f"{path} is not a readable HDF5 file: {error}") from error
    with file:
        if file.attrs.get("format") != FILE_FORMAT:
            raise CorruptEpisodeError(f"{path} is an HDF5 file but not a crowdteleop episode")
        try:
            attrs, demo = file.attrs, file[DEMO]
            env_args = attrs.get("env_args")
            return Episode(
                episode_id=str(attrs["episode_id"]),
                outcome=str(attrs["outcome"]),  # type: ignore[arg-type]  # written as an Outcome
                metadata=json.loads(attrs["metadata"]),
                model_xml=demo.attrs.get("model_file"),
                env_args=json.loads(env_args) if env_args is not None else None,
                created_at=float(attrs["created_at"]),
                finalized_at=float(attrs["finalized_at"]),
                recovered=bool(attrs["recovered"]),
                states=demo["states"][()],
                actions=demo["actions"][()],
                rewards=demo["rewards"][()],
                dones=demo["dones"][()],
                success=demo["success"][()],
                server_time=demo["server_time"][()],
                step_duration_s=demo["step_duration_s"][()],
                commands=[json.loads(c) for c in demo["commands/raw"].asstr()[()]],
                contacts=[json.loads(c) for c in demo["contacts"].asstr()[()]],
                labels=_read_labels(demo),
            )
        except (KeyError, ValueError, OSError) as error:
            raise CorruptEpisodeError(f"{path} is a damaged episode file: {error}") from error


def is_readable(path: Path) -> bool:
    try:
        _read_episode(path)
    except CorruptEpisodeError:
        return False
    return True
