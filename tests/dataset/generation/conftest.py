"""Source demonstrations for generation: scripted operators' episodes (OSC on Panda, the arm
robomimic's datasets use) recorded through the platform's control and recording path, and the
labelled dataset ``dataset build`` makes of them."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from crowdteleop.dataset.build import BuildOptions, build_dataset
from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig


@dataclass(frozen=True)
class Sources:
    episodes: Path  # the episode files
    dataset: Path  # built from them


def record_sources(root: Path, task: str, count: int) -> Sources:
    episodes = root / "episodes"
    kept, seed = 0, 0
    with scripted_rig(task, "osc", robot="Panda") as rig:
        while kept < count:
            episode = record_scripted_episode(rig, episodes, f"{task}-{seed}", seed)
            kept += episode.outcome == "success"  # the build leaves failures out
            seed += 1
    dataset = root / "sources.hdf5"
    build_dataset([episodes], dataset, BuildOptions(drift_tolerance=None))
    return Sources(episodes, dataset)


@pytest.fixture(scope="session")
def lift_sources(tmp_path_factory: pytest.TempPathFactory) -> Sources:
    return record_sources(tmp_path_factory.mktemp("lift-sources"), "lift", 3)


@pytest.fixture(scope="session")
def can_sources(tmp_path_factory: pytest.TempPathFactory) -> Sources:
    return record_sources(tmp_path_factory.mktemp("can-sources"), "pick-place-can", 2)
