"""``crowdteleop dataset export --format lerobot``: a LeRobotDataset v3.0 directory, laid out as
lerobot 0.4's ``LeRobotDataset`` writes one and its ``LeRobotDatasetMetadata`` reads it.

- ``meta/info.json``: integer ``fps``, ``features`` with ``names``, LeRobot's file sizes.
- ``meta/tasks.parquet``: the instruction as the pandas index ``task``, column ``task_index``.
- ``meta/stats.json``: min, max, mean, std, count, q01, q10, q50, q90, q99 per feature, exact
  over all frames (LeRobot's ``aggregate_stats`` averages episodes' quantiles); images per
  channel in [0, 1], shaped (3, 1, 1), counted in frames.
- ``meta/episodes/chunk-*/file-*.parquet``: a row per episode (``tasks``, ``length``, file
  indices, ``dataset_from_index``, ``videos/<key>/from_timestamp``, ``stats/<feature>/<stat>``,
  ``quality_score``: the demo's score in the source dataset, docs/quality.md, -1 if none;
  ``review_decision``: accepted, rejected, or "" if undecided, docs/review.md).
- ``data/`` and ``videos/<key>/``: whole episodes back to back, the next file where the next
  episode would pass the size limit; AV1 as LeRobot encodes (keyframe every 2 frames, crf 30).

``observation.state`` concatenates the low-dim observations, robot keys first, then the others
(``object``), each group alphabetically; its ``names`` say which entry is which.
"""

from __future__ import annotations

import io
import json
import os
import shutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.parquet as pq

from crowdteleop.dataset.export import (
    Observations,
    Progress,
    demo_names,
    render_observations,
    total_steps,
)
from crowdteleop.dataset.files import DatasetError, open_dataset
from crowdteleop.dataset.replay import Demo, ReplayChecker, load_demo
from crowdteleop.dataset.video import (
    LEROBOT_AV1,
    Mp4Files,
    VideoEncoding,
    encode_clip,
    video_info,
)
from crowdteleop.provenance.env_args import EnvArgs
from crowdteleop.recording.metadata import EpisodeMetadata
from crowdteleop.tasks import get_task

CHUNKS_SIZE = 1000  # files per chunk directory: LeRobot's DEFAULT_CHUNK_SIZE
DATA_FILES_SIZE_IN_MB = 100  # LeRobot's DEFAULT_DATA_FILE_SIZE_IN_MB
VIDEO_FILES_SIZE_IN_MB = 200  # LeRobot's DEFAULT_VIDEO_FILE_SIZE_IN_MB
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
QUANTILES = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}
OSC_ACTION_NAMES = ["dx", "dy", "dz", "drx", "dry", "drz", "gripper"]
FEATURE_DTYPES = {  # the non-video features, in the order LeRobot's `create` lists them
    "observation.state": "float32",
    "action": "float32",
    "next.reward": "float32",
    "next.done": "bool",
    "subtask_index": "int64",  # ours: the stage (meta/subtasks.parquet), -1 where unlabelled
    "timestamp": "float32",
    "frame_index": "int64",
    "episode_index": "int64",
    "index": "int64",
    "task_index": "int64",
}
_PARQUET: dict[str, Any] = {"compression": "snappy", "use_dictionary": True}
_MB = 1024**2


@dataclass(frozen=True)
class LeRobotLayout:
    """How the export's files are encoded and cut: LeRobot's own defaults unless changed
    (``encoding=LEROBOT_H264`` for H.264; small sizes to split episodes across files)."""

    encoding: VideoEncoding = LEROBOT_AV1
    data_files_size_in_mb: float = DATA_FILES_SIZE_IN_MB
    video_files_size_in_mb: float = VIDEO_FILES_SIZE_IN_MB


LEROBOT_LAYOUT = LeRobotLayout()


def state_keys(low_dim: Sequence[str]) -> list[str]:
    """The order ``observation.state`` concatenates low-dim keys in: robot first, then object."""
    return sorted(low_dim, key=lambda key: (not key.startswith("robot"), key))


def state_names(widths: dict[str, int]) -> list[str]:
    """One name per ``observation.state`` entry, from its key and position."""
    names: list[str] = []
    for key in state_keys(list(widths)):
        width = widths[key]
        axes: Sequence[object] = range(width)
        if key.endswith("_pos") and width == 3:
            axes = "xyz"
        elif key.endswith("_quat") and width == 4:
            axes = "xyzw"  # robosuite's (and our simulation's) quaternion order
        names += [key] if width == 1 else [f"{key}.{axis}" for axis in axes]
    return names


def action_names(info: EpisodeMetadata, width: int) -> list[str]:
    """Joint velocities + gripper (``ik-velocity``) or an end-effector twist + gripper (``osc``)."""
    mode = info.action_mode or ("osc-pose" if info.controller == "osc" else "joint-velocity")
    if mode == "osc-pose" and width == len(OSC_ACTION_NAMES):
        return OSC_ACTION_NAMES
    if mode == "joint-velocity":
        return [f"joint_{i}.velocity" for i in range(width - 1)] + ["gripper"]
    return [f"action.{i}" for i in range(width)]


def export_lerobot(
    dataset: Path,
    output: Path,
    cameras: Sequence[str],
    width: int,
    height: int,
    progress: Progress | None = None,
    layout: LeRobotLayout = LEROBOT_LAYOUT,
) -> Path:
    """A LeRobotDataset v3.0 directory, written whole or not at all (refuses a non-empty one)."""
    if output.exists() and any(output.iterdir()):
        raise DatasetError(f"{output} is not empty; choose a new directory for the export")
    names = demo_names(dataset)
    if not names:
        raise DatasetError(f"{dataset} holds no demos to export")
    hz = load_demo(dataset, names[0]).info.control_hz
    if abs(hz - round(hz)) > 1e-9:
        raise DatasetError(f"LeRobot needs whole frames per second; {dataset} runs at {hz} Hz")
    with open_dataset(dataset) as file:
        robots = EnvArgs.model_validate_json(file["data"].attrs["env_args"]).robots
    tmp = output.with_name(f".{output.name}.{os.getpid()}.tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    writer = _Writer(tmp, round(hz), cameras, layout)
    total, done = total_steps(dataset), 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    try:
        with ReplayChecker() as checker:
            for name in names:
                demo = load_demo(dataset, name)
                obs = render_observations(checker, demo, cameras, width, height, tick)
                with h5py.File(dataset, "r") as file:
                    group = file["data"][name]
                    rewards, dones = (group[key][()] for key in ("rewards", "dones"))
                    subtasks = subtask_names(group)
                    columns = episode_columns(group.attrs)
                writer.add_episode(demo, obs, rewards, dones, subtasks, columns)
        writer.finish("-".join(robots or ["Sawyer"]).lower())
        if output.exists():
            output.rmdir()  # empty, checked above
        os.replace(tmp, output)
    finally:
        writer.close()
        shutil.rmtree(tmp, ignore_errors=True)
    return output


def episode_columns(attrs: Mapping[str, Any]) -> dict[str, Any]:
    """A demo's quality and review as columns of meta/episodes (docs/quality.md, review.md):
    `quality_score` (-1: not scored) and `review_decision` ("": undecided)."""
    decision = attrs.get("review_decision", "")
    return {
        "quality_score": float(attrs.get("quality_score", -1.0)),
        "review_decision": decision.decode() if isinstance(decision, bytes) else str(decision),
    }


class _Writer:
    """Episodes into the directory ``root``: frames and clips as they come, the metadata (which
    needs every episode) at ``finish``."""

    def __init__(
        self,
        root: Path,
        fps: int,
        cameras: Sequence[str],
        layout: LeRobotLayout,
    ) -> None:
        self.root, self.fps, self.layout = root, fps, layout
        self.cameras = {camera: f"observation.images.{camera}" for camera in cameras}
        self.data = _ParquetFiles(_paths(root, DATA_PATH), layout.data_files_size_in_mb * _MB)
        video_bytes = layout.video_files_size_in_mb * _MB
        self.videos = {
            key: Mp4Files(_paths(root, VIDEO_PATH, video_key=key), video_bytes)
            for key in self.cameras.values()
        }
        self.columns: dict[str, list[npt.NDArray[Any]]] = {}
        self.images = {key: _ImageStats() for key in self.cameras.values()}
        self.episodes: list[dict[str, Any]] = []
        self.tasks: dict[str, int] = {}
        self.subtasks: dict[str, int] = {}  # "reach (cube)" -> subtask_index
        self.names: tuple[list[str], list[str]] | None = None  # state's, action's

    def add_episode(
        self,
        demo: Demo,
        obs: Observations,
        rewards: npt.NDArray[Any],
        dones: npt.NDArray[Any],
        subtasks: list[str] | None = None,
        columns: Mapping[str, Any] | None = None,
    ) -> None:
        keys = state_keys(list(obs.low_dim))
        widths = {key: obs.low_dim[key].shape[1] for key in keys}
        names = (state_names(widths), action_names(demo.info, demo.actions.shape[1]))
        if self.names not in (None, names):
            raise DatasetError(f"{demo.name} has other observations or actions than demo 1")
        self.names = names
        task = get_task(demo.info.task).instruction
        episode, n = len(self.episodes), len(demo.actions)
        start = self.episodes[-1]["dataset_to_index"] if self.episodes else 0
        frame = {
            "observation.state": np.concatenate([obs.low_dim[k] for k in keys], axis=1),
            "action": demo.actions,
            "next.reward": rewards[:, None],
            "next.done": dones[:, None],
            "timestamp": (np.arange(n) / self.fps)[:, None],
            "frame_index": np.arange(n)[:, None],
            "episode_index": np.full((n, 1), episode),
            "index": np.arange(start, start + n)[:, None],
            "task_index": np.full((n, 1), self.tasks.setdefault(task, len(self.tasks))),
            "subtask_index": np.array(
                [self.subtasks.setdefault(s, len(self.subtasks)) for s in subtasks]
                if subtasks is not None
                else [-1] * n
            )[:, None],
        }
        frame = {key: value.astype(FEATURE_DTYPES[key]) for key, value in frame.items()}
        data_file = self.data.append(_frame_table(frame))
        entry: dict[str, Any] = {"episode_index": episode, "tasks": [task], "length": n}
        entry |= columns or episode_columns({})
        entry |= _indices(data_file, "data/")
        entry |= {"dataset_from_index": start, "dataset_to_index": start + n}
        stats: dict[str, dict[str, Any]] = {key: _stats(a) for key, a in frame.items()}
        for camera, key in self.cameras.items():
            clip = encode_clip(obs.images[camera], self.fps, self.layout.encoding)
            placed = self.videos[key].append(clip)
            entry |= _indices(placed.file, f"videos/{key}/")
            entry |= {f"videos/{key}/from_timestamp": placed.start_s}
            entry |= {f"videos/{key}/to_timestamp": placed.end_s}
            images = _ImageStats().add(obs.images[camera])
            self.images[key].merge(images)
            stats[key] = images.result()
        for feature, values in stats.items():
            entry |= {f"stats/{feature}/{stat}": value for stat, value in values.items()}
        self.episodes.append(entry)
        for key, array in frame.items():
            self.columns.setdefault(key, []).append(array)

    def finish(self, robot_type: str) -> None:
        """The last data and video files, then the metadata: episodes, tasks, stats and info."""
        assert self.names is not None
        self.close()
        meta_bytes = self.layout.data_files_size_in_mb * _MB
        meta = _ParquetFiles(_paths(self.root, EPISODES_PATH), meta_bytes)
        for entry in self.episodes:  # placed with a stand-in file index, stamped when written
            meta.append(pa.Table.from_pylist([entry | _indices(0, "meta/episodes/")]))
        meta.flush()
        _write_index(self.root / "meta" / "tasks.parquet", "task", self.tasks)
        _write_index(self.root / "meta" / "subtasks.parquet", "subtask", self.subtasks)
        stats = {key: _stats(np.concatenate(arrays)) for key, arrays in self.columns.items()}
        stats |= {key: images.result() for key, images in self.images.items()}
        state, action = self.names
        features: dict[str, Any] = {
            key: {"dtype": dtype, "shape": [1], "names": None}
            for key, dtype in FEATURE_DTYPES.items()
        }
        features["observation.state"] |= {"shape": [len(state)], "names": state}
        features["action"] |= {"shape": [len(action)], "names": action}
        for key in self.cameras.values():
            info = video_info(self.videos[key].path_of(0))
            shape = [info["video.height"], info["video.width"], info["video.channels"]]
            names = ["height", "width", "channels"]
            features[key] = {"dtype": "video", "shape": shape, "names": names, "info": info}
        for key in ("timestamp", "frame_index", "episode_index", "index", "task_index"):
            features[key] = features.pop(key)  # LeRobot's DEFAULT_FEATURES come last
        info = {
            "codebase_version": "v3.0",
            "robot_type": robot_type,
            "total_episodes": len(self.episodes),
            "total_frames": self.episodes[-1]["dataset_to_index"],
            "total_tasks": len(self.tasks),
            "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": self.layout.data_files_size_in_mb,
            "video_files_size_in_mb": self.layout.video_files_size_in_mb,
            "fps": self.fps,
            "splits": {"train": f"0:{len(self.episodes)}"},
            "data_path": DATA_PATH,
            "video_path": VIDEO_PATH if self.cameras else None,
            "features": features,
        }
        (self.root / "meta" / "info.json").write_text(json.dumps(info, indent=4))
        (self.root / "meta" / "stats.json").write_text(json.dumps(stats, indent=4))

    def close(self) -> None:
        """Writes the pending data file and finishes the video files."""
        self.data.flush()
        for videos in self.videos.values():
            videos.close()


def _paths(root: Path, template: str, **keys: str) -> Callable[[int], Path]:
    """File n of a LeRobot path template: chunk n // CHUNKS_SIZE, file n % CHUNKS_SIZE."""
    return lambda n: root / template.format(**_indices(n), **keys)


def _indices(n: int, prefix: str = "") -> dict[str, int]:
    """File n's ``<prefix>chunk_index`` and ``<prefix>file_index`` (episodes say where they are)."""
    chunk, file = divmod(n, CHUNKS_SIZE)
    return {f"{prefix}chunk_index": chunk, f"{prefix}file_index": file}


def _frame_table(frame: dict[str, npt.NDArray[Any]]) -> pa.Table:
    """The episode's rows as LeRobot's features type them: vectors as fixed-size lists."""
    columns: dict[str, pa.Array] = {}
    for key, array in frame.items():
        if key in ("observation.state", "action"):
            values = pa.array(array.ravel())
            columns[key] = pa.FixedSizeListArray.from_arrays(values, array.shape[1])
        else:
            columns[key] = pa.array(array[:, 0])
    return pa.table(columns)


def _stats(array: npt.NDArray[Any]) -> dict[str, list[float] | list[int]]:
    """LeRobot's per-feature statistics of (N, D) values; quantiles exact (linear)."""
    values = array.astype(np.float64)
    stats: dict[str, list[float] | list[int]] = {
        "min": values.min(axis=0).tolist(),
        "max": values.max(axis=0).tolist(),
        "mean": values.mean(axis=0).tolist(),
        "std": values.std(axis=0).tolist(),
        "count": [len(values)],
    }
    for key, q in QUANTILES.items():
        stats[key] = np.quantile(values, q, axis=0).tolist()
    return stats


class _ImageStats:
    """Per-channel statistics of uint8 frames in [0, 1], from 256-bin histograms (so exact and
    mergeable); shaped (3, 1, 1) and counted in frames, as LeRobot keeps them."""

    def __init__(self) -> None:
        self.frames = 0
        self.histogram = np.zeros((3, 256), dtype=np.int64)

    def add(self, images: npt.NDArray[np.uint8]) -> _ImageStats:
        self.frames += len(images)
        for channel in range(3):
            self.histogram[channel] += np.bincount(images[..., channel].ravel(), minlength=256)
        return self

    def merge(self, other: _ImageStats) -> None:
        self.frames += other.frames
        self.histogram += other.histogram

    def result(self) -> dict[str, Any]:
        levels = np.arange(256) / 255.0
        total = self.histogram.sum(axis=1)
        mean = self.histogram @ levels / total
        std = np.sqrt(np.maximum(self.histogram @ levels**2 / total - mean**2, 0.0))
        below = np.cumsum(self.histogram, axis=1) / total[:, None]
        present = self.histogram > 0
        stats: dict[str, Any] = {
            "min": levels[present.argmax(axis=1)],
            "max": levels[255 - present[:, ::-1].argmax(axis=1)],
            "mean": mean,
            "std": std,
        }
        for key, q in QUANTILES.items():  # the lowest level at or below which q of the pixels lie
            stats[key] = levels[np.minimum((below < q - 1e-12).sum(axis=1), 255)]
        shaped = {key: [[[float(x)]] for x in value] for key, value in stats.items()}
        return shaped | {"count": [self.frames]}


class _ParquetFiles:
    """Tables back to back in files ``path_of(0)``, ``path_of(1)``, ...; the next file starts
    where the next table would take this one past ``max_bytes``. A table's size is measured by
    writing it alone, which overstates its share (one footer per file, not per table)."""

    def __init__(self, path_of: Callable[[int], Path], max_bytes: float) -> None:
        self.path_of, self.max_bytes = path_of, max_bytes
        self.file, self.used = 0, 0
        self._pending: list[pa.Table] = []

    def append(self, table: pa.Table) -> int:
        """Adds ``table``; returns the number of the file it goes to."""
        buffer = io.BytesIO()
        pq.write_table(table, buffer, **_PARQUET)
        if self._pending and self.used + buffer.tell() > self.max_bytes:
            self.flush()
            self.file += 1
        self._pending.append(table)
        self.used += buffer.tell()
        return self.file

    def flush(self) -> None:
        """Writes the current file. ``meta/episodes`` rows get the file they are in stamped."""
        if not self._pending:
            return
        table = pa.concat_tables(self._pending)
        for name, value in _indices(self.file, "meta/episodes/").items():
            if name in table.column_names:
                column = pa.array([value] * len(table), pa.int64())
                table = table.set_column(table.column_names.index(name), name, column)
        path = self.path_of(self.file)
        path.parent.mkdir(parents=True, exist_ok=True)
        pq.write_table(table, path, **_PARQUET)
        self._pending, self.used = [], 0


def subtask_names(group: h5py.Group) -> list[str] | None:
    """Each step's subtask as the export names it ("reach (cube)", "done"), from the demo's
    labels (``datagen_info``); None for a dataset built before labels existed."""
    if "datagen_info" not in group:
        return None
    info = group["datagen_info"]
    stages, objects = (info[key].asstr()[()] for key in ("stage", "relative_to"))
    return [f"{s} ({o})" if o else s for s, o in zip(stages, objects, strict=True)]


def _write_index(path: Path, name: str, indices: dict[str, int]) -> None:
    """``meta/tasks.parquet`` (and ``subtasks.parquet``) as pandas writes a frame indexed by the
    string: LeRobot reads it with ``pd.read_parquet`` and takes each frame's task from the index
    label."""
    columns = [(f"{name}_index", "int64", "int64"), (name, "unicode", "object")]
    described = [
        {"name": n, "field_name": n, "pandas_type": t, "numpy_type": d, "metadata": None}
        for n, t, d in columns
    ]
    pandas = {"index_columns": [name], "column_indexes": [], "columns": described}
    index = pa.array(list(indices.values()), pa.int64())
    table = pa.table({f"{name}_index": index, name: [*indices]})
    table = table.replace_schema_metadata({"pandas": json.dumps(pandas)})
    pq.write_table(table, path)
