"""A tiny low-dim dataset to learn from: scripted lift demos (OSC), built by ``dataset build``,
with each step's observations (``sim.observations()`` at the recorded state) written under
``data/demo_k/obs/<key>`` where the build did not write them itself."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import numpy as np
import pytest

from crowdteleop.dataset.build import BuildOptions, build_dataset
from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

N_DEMOS = 3


def add_low_dim_obs(path: Path) -> None:
    """``obs/<key>`` and ``next_obs/<key>`` for every demo, from its states, in the
    simulation its metadata names (what ``dataset build --obs low-dim`` writes)."""
    from crowdteleop.sim import SimConfig, make_simulation

    with h5py.File(path, "r+") as file:
        demos = list(file["data"])
        if all("obs" in file["data"][name] for name in demos):
            return
        sim_config = json.loads(file["data"][demos[0]].attrs["metadata"])["sim_config"]
        sim = make_simulation(SimConfig(**sim_config))
        try:
            for name in demos:
                group = file["data"][name]
                frames = []
                for state in group["states"][()]:
                    sim.set_state(state)
                    frames.append(sim.observations())
                # the state after the last action: one step from the last recorded state
                keys = list(frames[0])
                for key in keys:
                    series = np.stack([f[key] for f in frames])
                    group.create_dataset(f"obs/{key}", data=series)
                    group.create_dataset(
                        f"next_obs/{key}", data=np.concatenate([series[1:], series[-1:]])
                    )
        finally:
            sim.close()


@pytest.fixture(scope="session")
def lift_dataset(tmp_path_factory) -> Path:
    episodes = tmp_path_factory.mktemp("learn-episodes")
    with scripted_rig("lift", "osc") as rig:
        for seed in range(N_DEMOS):
            assert record_scripted_episode(rig, episodes, f"lift-{seed}", seed).outcome == "success"
    output = tmp_path_factory.mktemp("learn-dataset") / "lift.hdf5"
    build_dataset([episodes], output, BuildOptions(drift_tolerance=None, valid_fraction=0.34))
    add_low_dim_obs(output)
    return output
