"""``crowdteleop dataset export``: image observations re-rendered from the recorded states.

``robomimic``: a copy of the dataset with ``obs`` / ``next_obs`` per demo (``<camera>_image``
uint8 HxWx3, ``robot0_eef_pos``, ``robot0_eef_quat``, ``robot0_joint_pos``,
``robot0_gripper_qpos``, ``object``: robosuite's observables), what robomimic's
``dataset_states_to_obs.py`` adds.
"""

from __future__ import annotations

import json
import os
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import numpy.typing as npt

from crowdteleop.dataset.files import open_dataset
from crowdteleop.dataset.replay import Demo, ReplayChecker, load_demo

Progress = Callable[[int, int], None]
# robosuite's observation keys (robomimic's names) an export carries beside images: the
# stock BC configs' four and the arm's joints.
LOW_DIM = ("robot0_joint_pos", "robot0_eef_pos", "robot0_eef_quat", "robot0_gripper_qpos", "object")


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
    """Set each recorded state, render every camera and read robosuite's observables."""
    sim = checker.simulation(demo)
    images: dict[str, list[npt.NDArray[np.uint8]]] = {camera: [] for camera in cameras}
    low: dict[str, list[npt.NDArray[np.float64]]] = {key: [] for key in LOW_DIM}
    for state in demo.states:
        sim.set_state(state)
        for camera in cameras:
            images[camera].append(sim.render(camera, width, height).copy())
        observed = sim.observations()
        for key in LOW_DIM:
            low[key].append(observed[key])
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
                    for folder in ("obs", "next_obs"):  # the build's own, recomputed
                        if f"{folder}/{key}" in group:
                            del group[f"{folder}/{key}"]
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


def _frame_counter(progress: Progress | None, total: int) -> Callable[[], None]:
    """A callback for each rendered frame that reports (frames done, total) to ``progress``."""
    done = 0

    def tick() -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(done, total)

    return tick
