"""The source dataset as generation reads it: each demo's labels, and the recording that
rebuilds the simulation they were made on."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import h5py

from crowdteleop.dataset.files import DatasetError, open_dataset
from crowdteleop.dataset.generation.labels import DemoLabels, read_datagen_info
from crowdteleop.dataset.replay import Demo
from crowdteleop.recording.metadata import EpisodeMetadata


@dataclass(frozen=True)
class Sources:
    """The source dataset as generation reads it."""

    path: Path
    demos: list[DemoLabels]
    first: Demo  # rebuilds the simulation every source was recorded on

    @property
    def metadata(self) -> EpisodeMetadata:
        return self.first.info


def read_sources(path: Path) -> Sources:
    """Every demo's labels; clear errors for a dataset without them or of several setups."""
    from crowdteleop.dataset.replay import load_demo

    with open_dataset(path) as file:
        names = sorted(file["data"], key=lambda n: int(n.split("_")[-1]))
        if not names:
            raise DatasetError(f"{path} holds no demonstrations")
        demos = [read_datagen_info(file["data"][name], name) for name in names]
        configs = {_sim_config(file["data"][name]) for name in names}
    if len(configs) > 1:
        raise DatasetError(
            f"{path}: its demos were recorded on {len(configs)} simulation setups (task, robot, "
            "controller...); generate from one"
        )
    first = load_demo(path, names[0])
    if first.info.controller != "osc":
        raise DatasetError(
            f"{path} was recorded with the {first.info.controller} controller: generation "
            "executes absolute OSC targets, so its sources are OSC recordings (--controller osc)"
        )
    return Sources(path, demos, first)


def _sim_config(group: h5py.Group) -> str:
    return json.dumps(json.loads(group.attrs["metadata"]).get("sim_config"), sort_keys=True)
