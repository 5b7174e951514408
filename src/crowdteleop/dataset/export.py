"""``crowdteleop dataset export``: image observations re-rendered from the recorded states.

``robomimic``: a copy of the dataset with ``obs`` / ``next_obs`` per demo (``<camera>_image``
uint8 HxWx3, ``robot0_eef_pos``, ``robot0_eef_quat``, ``robot0_joint_pos``,
``robot0_gripper_closed``), what robomimic's ``dataset_states_to_obs.py`` adds.
``lerobot``: a LeRobotDataset v3.0 directory: ``meta/info.json``, ``meta/stats.json``,
``meta/tasks.parquet``, ``meta/episodes/chunk-000/file-000.parquet``,
``data/chunk-000/file-000.parquet`` (every episode's frames) and
``videos/observation.images.<camera>/chunk-000/file-000.mp4`` (every episode back to back).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import numpy.typing as npt

from crowdteleop.dataset.files import DatasetError, open_dataset
from crowdteleop.dataset.replay import Demo, ReplayChecker, load_demo

Progress = Callable[[int, int], None]
LOW_DIM = {"robot0_eef_pos": 3, "robot0_eef_quat": 4, "robot0_gripper_closed": 1}


@dataclass(frozen=True)
class Observations:
    images: dict[str, npt.NDArray[np.uint8]]  # camera -> (N, H, W, 3)
    low_dim: dict[str, npt.NDArray[np.float64]]  # key -> (N, D) float64


def render_observations(
    checker: ReplayChecker,
    demo: Demo,
    cameras: Sequence[str],
    width: int,
    height: int,
    tick: Callable[[], None] | None = None,
) -> Observations:
    """Set each recorded state, render every camera and read the robot's proprioception."""
    sim = checker.simulation(demo)
    images: dict[str, list[npt.NDArray[np.uint8]]] = {camera: [] for camera in cameras}
    low: dict[str, list[npt.NDArray[np.float64]]] = {
        key: [] for key in (*LOW_DIM, "robot0_joint_pos")
    }
    for state in demo.states:
        sim.set_state(state)
        for camera in cameras:
            images[camera].append(sim.render(camera, width, height).copy())
        robot = sim.robot_state()
        low["robot0_eef_pos"].append(robot.end_effector.position.copy())
        low["robot0_eef_quat"].append(robot.end_effector.quaternion.copy())
        low["robot0_gripper_closed"].append(np.array([robot.gripper_closed_fraction]))
        low["robot0_joint_pos"].append(robot.joint_positions.copy())
        if tick is not None:
            tick()
    return Observations(
        {camera: np.stack(frames) for camera, frames in images.items()},
        {key: np.stack(rows).astype(np.float64) for key, rows in low.items()},
    )


def demo_names(path: Path) -> list[str]:
    with open_dataset(path) as file:
        return sorted(file["data"], key=lambda n: int(n.split("_")[-1]))


def total_steps(path: Path) -> int:
    with open_dataset(path) as file:
        return int(file["data"].attrs["total"])


def export_robomimic(
    dataset: Path,
    output: Path,
    cameras: Sequence[str],
    width: int,
    height: int,
    progress: Progress | None = None,
) -> Path:
    """A copy of ``dataset`` with image and low-dim observations (written whole or not at all)."""
    names, total = demo_names(dataset), total_steps(dataset)
    tmp = output.with_name(f".{output.name}.{os.getpid()}.tmp")
    output.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(dataset, tmp)
    tick = _frame_counter(progress, total)
    try:
        with ReplayChecker() as checker, h5py.File(tmp, "a") as file:
            for name in names:
                demo = load_demo(dataset, name)
                obs = render_observations(checker, demo, cameras, width, height, tick)
                group = file["data"][name]
                columns = {f"{c}_image": a for c, a in obs.images.items()} | obs.low_dim
                for key, array in columns.items():
                    group.create_dataset(f"obs/{key}", data=array, compression="gzip")
                    shifted = np.concatenate([array[1:], array[-1:]])
                    group.create_dataset(f"next_obs/{key}", data=shifted, compression="gzip")
            file["data"].attrs["image_cameras"] = json.dumps(list(cameras))
        with open(tmp, "rb") as handle:
            os.fsync(handle.fileno())
        os.replace(tmp, output)
    finally:
        tmp.unlink(missing_ok=True)
    return output


def export_lerobot(
    dataset: Path,
    output: Path,
    cameras: Sequence[str],
    width: int,
    height: int,
    progress: Progress | None = None,
) -> Path:
    """A LeRobotDataset v3.0 directory (refuses to write into a non-empty one)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from crowdteleop.dataset.video import Mp4Writer
    from crowdteleop.tasks import get_task

    if output.exists() and any(output.iterdir()):
        raise DatasetError(f"{output} is not empty; choose a new directory for the export")
    names, total = demo_names(dataset), total_steps(dataset)
    with open_dataset(dataset) as file:
        env_args = json.loads(file["data"].attrs["env_args"])
    frames: dict[str, list[Any]] = {
        key: []
        for key in (
            "observation.state",
            "action",
            "timestamp",
            "frame_index",
            "episode_index",
            "index",
            "task_index",
            "next.reward",
            "next.done",
        )
    }
    episodes: list[dict[str, Any]] = []
    tasks: dict[str, int] = {}
    image_stats = {camera: _RunningImageStats() for camera in cameras}
    video_keys = [f"observation.images.{camera}" for camera in cameras]
    fps = load_demo(dataset, names[0]).info.control_hz
    tick = _frame_counter(progress, total)
    with ReplayChecker() as checker, contextlib.ExitStack() as stack:
        writers = {
            key: stack.enter_context(
                Mp4Writer(output / "videos" / key / "chunk-000" / "file-000.mp4", round(fps))
            )
            for key in video_keys
        }
        for episode_index, name in enumerate(names):
            demo = load_demo(dataset, name)
            obs = render_observations(checker, demo, cameras, width, height, tick)
            task = get_task(demo.info.task).instruction
            task_index = tasks.setdefault(task, len(tasks))
            n = len(demo.states)
            start = len(frames["index"])
            state = np.concatenate(
                [
                    obs.low_dim["robot0_joint_pos"],
                    obs.low_dim["robot0_eef_pos"],
                    obs.low_dim["robot0_eef_quat"],
                    obs.low_dim["robot0_gripper_closed"],
                ],
                axis=1,
            ).astype(np.float32)
            with h5py.File(dataset, "r") as file:
                rewards = file["data"][name]["rewards"][()]
                dones = file["data"][name]["dones"][()]
            frames["observation.state"] += list(state)
            frames["action"] += list(demo.actions.astype(np.float32))
            frames["timestamp"] += list((np.arange(n) / fps).astype(np.float32))
            frames["frame_index"] += list(range(n))
            frames["episode_index"] += [episode_index] * n
            frames["index"] += list(range(start, start + n))
            frames["task_index"] += [task_index] * n
            frames["next.reward"] += list(rewards.astype(np.float32))
            frames["next.done"] += list(dones.astype(bool))
            entry: dict[str, Any] = {
                "episode_index": episode_index,
                "tasks": [task],
                "length": n,
                "data/chunk_index": 0,
                "data/file_index": 0,
                "dataset_from_index": start,
                "dataset_to_index": start + n,
                "meta/episodes/chunk_index": 0,
                "meta/episodes/file_index": 0,
            }
            for camera, key in zip(cameras, video_keys, strict=True):
                before = writers[key].frames_written
                for image in obs.images[camera]:
                    writers[key].write(image)
                image_stats[camera].add(obs.images[camera])
                entry[f"videos/{key}/chunk_index"] = 0
                entry[f"videos/{key}/file_index"] = 0
                entry[f"videos/{key}/from_timestamp"] = before / fps
                entry[f"videos/{key}/to_timestamp"] = (before + n) / fps
            episodes.append(entry)
    state_dim = len(frames["observation.state"][0])
    action_dim = len(frames["action"][0])
    table = pa.table(
        {
            "observation.state": pa.array(
                [list(map(float, r)) for r in frames["observation.state"]],
                type=pa.list_(pa.float32(), state_dim),
            ),
            "action": pa.array(
                [list(map(float, r)) for r in frames["action"]],
                type=pa.list_(pa.float32(), action_dim),
            ),
            "timestamp": pa.array(frames["timestamp"], type=pa.float32()),
            "frame_index": pa.array(frames["frame_index"], type=pa.int64()),
            "episode_index": pa.array(frames["episode_index"], type=pa.int64()),
            "index": pa.array(frames["index"], type=pa.int64()),
            "task_index": pa.array(frames["task_index"], type=pa.int64()),
            "next.reward": pa.array(frames["next.reward"], type=pa.float32()),
            "next.done": pa.array(frames["next.done"], type=pa.bool_()),
        }
    )
    _write_parquet(pq, table, output / "data" / "chunk-000" / "file-000.parquet")
    _write_parquet(
        pq,
        pa.Table.from_pylist(episodes),
        output / "meta" / "episodes" / "chunk-000" / "file-000.parquet",
    )
    _write_parquet(
        pq,
        pa.table({"task_index": list(tasks.values()), "task": list(tasks)}),
        output / "meta" / "tasks.parquet",
    )
    stats = {
        "observation.state": _stats(np.array(frames["observation.state"])),
        "action": _stats(np.array(frames["action"])),
        "timestamp": _stats(np.array(frames["timestamp"])[:, None]),
        "next.reward": _stats(np.array(frames["next.reward"])[:, None]),
    } | {key: image_stats[c].result() for c, key in zip(cameras, video_keys, strict=True)}
    info = _info(
        env_args,
        len(names),
        len(frames["index"]),
        len(tasks),
        fps,
        state_dim,
        action_dim,
        video_keys,
        width,
        height,
    )
    (output / "meta" / "info.json").write_text(json.dumps(info, indent=2))
    (output / "meta" / "stats.json").write_text(json.dumps(stats, indent=2))
    return output


def _write_parquet(pq: Any, table: Any, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    pq.write_table(table, path)


def _stats(array: npt.NDArray[np.float64]) -> dict[str, list[float] | list[int]]:
    return {
        "min": array.min(axis=0).tolist(),
        "max": array.max(axis=0).tolist(),
        "mean": array.mean(axis=0).tolist(),
        "std": array.std(axis=0).tolist(),
        "count": [len(array)],
    }


class _RunningImageStats:
    """Per-channel min/max/mean/std in [0, 1], shaped (3, 1, 1) as LeRobot keeps them."""

    def __init__(self) -> None:
        self.n = 0
        self.total = np.zeros(3)
        self.squares = np.zeros(3)
        self.low = np.ones(3)
        self.high = np.zeros(3)

    def add(self, images: npt.NDArray[np.uint8]) -> None:
        pixels = images.reshape(-1, 3).astype(np.float64) / 255.0
        self.n += len(pixels)
        self.total += pixels.sum(axis=0)
        self.squares += (pixels**2).sum(axis=0)
        self.low = np.minimum(self.low, pixels.min(axis=0))
        self.high = np.maximum(self.high, pixels.max(axis=0))

    def result(self) -> dict[str, Any]:
        mean = self.total / max(self.n, 1)
        std = np.sqrt(np.maximum(self.squares / max(self.n, 1) - mean**2, 0.0))

        def shaped(v: npt.NDArray[np.float64]) -> list[list[list[float]]]:
            return [[[float(x)]] for x in v]

        return {
            "min": shaped(self.low),
            "max": shaped(self.high),
            "mean": shaped(mean),
            "std": shaped(std),
            "count": [self.n],
        }


def _info(
    env_args: dict[str, Any],
    episodes: int,
    frames: int,
    tasks: int,
    fps: float,
    state_dim: int,
    action_dim: int,
    video_keys: list[str],
    width: int,
    height: int,
) -> dict[str, Any]:
    robots = env_args.get("env_kwargs", {}).get("robots", ["Sawyer"])
    scalar = {"shape": [1], "names": None}
    features: dict[str, Any] = {
        "observation.state": {"dtype": "float32", "shape": [state_dim], "names": None},
        "action": {"dtype": "float32", "shape": [action_dim], "names": None},
        "timestamp": {"dtype": "float32", **scalar},
        "frame_index": {"dtype": "int64", **scalar},
        "episode_index": {"dtype": "int64", **scalar},
        "index": {"dtype": "int64", **scalar},
        "task_index": {"dtype": "int64", **scalar},
        "next.reward": {"dtype": "float32", **scalar},
        "next.done": {"dtype": "bool", **scalar},
    }
    for key in video_keys:
        features[key] = {
            "dtype": "video",
            "shape": [height, width, 3],
            "names": ["height", "width", "channels"],
            "info": {
                "video.height": height,
                "video.width": width,
                "video.codec": "h264",
                "video.pix_fmt": "yuv420p",
                "video.is_depth_map": False,
                "video.fps": fps,
                "video.channels": 3,
                "has_audio": False,
            },
        }
    return {
        "codebase_version": "v3.0",
        "robot_type": "-".join(robots).lower(),
        "total_episodes": episodes,
        "total_frames": frames,
        "total_tasks": tasks,
        "chunks_size": 1000,
        "data_files_size_in_mb": 100,
        "video_files_size_in_mb": 500,
        "fps": fps,
        "splits": {"train": f"0:{episodes}"},
        "data_path": "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet",
        "video_path": "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4",
        "features": features,
    }


def _frame_counter(progress: Progress | None, total: int) -> Callable[[], None]:
    """A callback for each rendered frame that reports (frames done, total) to ``progress``."""
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    return tick
