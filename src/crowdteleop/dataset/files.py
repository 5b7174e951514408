"""Built datasets, read back: what identifies one, and the per-demo summaries its attributes
hold. Used by replay, export and stats; `crowdteleop.dataset.build` writes them."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import h5py

from crowdteleop.errors import CrowdteleopError

DATASET_FORMAT = "crowdteleop-dataset"
NO_REGION = "none"  # the region of a demo whose campaign had none (or of an older dataset)


class DatasetError(CrowdteleopError, ValueError):
    """Inputs that cannot make a dataset, or a file that is not one of our datasets."""


@dataclass(frozen=True)
class DemoSummary:
    """What stats and filter keys need of one demonstration."""

    name: str
    episode_id: str
    task: str
    outcome: str
    interface: str
    worker: str
    network: str
    campaign: str
    steps: int
    completion_s: float
    drift: float | None = None
    region: str = NO_REGION


def open_dataset(path: Path) -> h5py.File:
    """One of our datasets, open for reading; anything else raises ``DatasetError``."""
    try:
        file = h5py.File(path, "r")
    except OSError as error:
        raise DatasetError(f"{path} is not a readable HDF5 file: {error}") from error
    if file.attrs.get("format") != DATASET_FORMAT or "data" not in file:
        file.close()
        raise DatasetError(
            f"{path} is not a crowdteleop dataset (build one with `crowdteleop dataset build`)"
        )
    return file


def dataset_demos(path: Path) -> list[DemoSummary]:
    """Summaries of every demo in a built dataset, in order."""
    with open_dataset(path) as file:
        summaries = []
        for name in sorted(file["data"], key=lambda n: int(n.split("_")[-1])):
            attrs = file["data"][name].attrs
            drift = float(attrs.get("action_replay_drift", -1.0))
            summaries.append(
                DemoSummary(
                    name=name,
                    episode_id=str(attrs["episode_id"]),
                    task=str(attrs["task"]),
                    outcome=str(attrs["outcome"]),
                    interface=str(attrs["interface"]),
                    worker=str(attrs["worker"]),
                    network=str(attrs["network_condition"]),
                    campaign=str(attrs["campaign"]),
                    steps=int(attrs["num_samples"]),
                    completion_s=float(attrs["completion_time_s"]),
                    drift=None if drift < 0 else drift,
                    region=str(attrs.get("region", NO_REGION)),
                )
            )
        return summaries
