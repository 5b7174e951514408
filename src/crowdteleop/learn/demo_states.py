"""Start states drawn out of demonstrations: the paper's demonstration-guided resets (its
Appendix: "with 90% probability, a demonstration was sampled uniformly at random from the
demonstration set, and the simulator was reset to a state sampled uniformly from the selected
demonstration, and with 10% probability, the environment was reset normally").

A state is restored exactly: the demo's own model (checked against its ``model_file``), the
reset that began its episode (robosuite's OSC keeps the episode's first joint posture as its
null-space target, outside the state), then ``[time, qpos, qvel]`` and the controller state
(robosuite's finger ramp) recorded at that step.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np
import numpy.typing as npt

from crowdteleop.learn.data import (
    LearnDataError,
    attr_text,
    demo_names,
    filter_members,
    open_learn_dataset,
)
from crowdteleop.sim.config import SimConfig

Array = npt.NDArray[np.float64]


@dataclass(frozen=True)
class DemoTrajectory:
    """One demonstration's states, as restoring them needs."""

    name: str
    states: Array  # (N, 1 + nq + nv)
    controller_states: Array  # (N, k): k = 0 for a backend without controller memory
    actions: Array  # (N, A), the recorded actions (to check a restore against the next state)
    model_xml: str
    sim_config: dict[str, object]
    reset_seed: int | None

    def __len__(self) -> int:
        return len(self.states)


@dataclass(frozen=True)
class StartState:
    """Where a demonstration-guided reset put the simulation."""

    demo: int  # index into `DemoStates.demos`
    step: int


class DemoStates:
    """The demonstrations a reset may start from, and the draw the paper describes: a demo
    uniformly, then one of its steps uniformly (not all steps uniformly, which would favour
    long demos)."""

    def __init__(self, demos: list[DemoTrajectory]) -> None:
        if not demos:
            raise LearnDataError("demonstration-guided resets need at least one demonstration")
        configs = {json.dumps(d.sim_config, sort_keys=True) for d in demos}
        if len(configs) > 1:
            raise LearnDataError(
                f"the demonstrations were recorded with {len(configs)} different sim_configs; "
                "resets need one simulation: split the dataset by configuration (dataset build "
                "--filter) and train on one part"
            )
        self.demos = demos

    @property
    def sim_config(self) -> dict[str, object]:
        return self.demos[0].sim_config

    def draw(self, rng: np.random.Generator) -> StartState:
        demo = int(rng.integers(len(self.demos)))
        return StartState(demo, int(rng.integers(len(self.demos[demo]))))


def load_demo_states(
    path: Path, limit: int | None = None, filter_key: str | None = None
) -> DemoStates:
    """The first ``limit`` demos (all when None) of a built dataset, in the order of
    ``mask/<filter_key>`` (or of their numbers), with what restoring their states needs."""
    with open_learn_dataset(path) as file:
        names = filter_members(file, filter_key) if filter_key else demo_names(file["data"])
        if limit is not None:
            if limit > len(names):
                raise LearnDataError(
                    f"{path} holds {len(names)} demonstrations"
                    f"{f' under mask/{filter_key}' if filter_key else ''}; {limit} were asked for"
                )
            names = names[:limit]
        return DemoStates([_trajectory(file["data"][name], name) for name in names])


def _trajectory(group: h5py.Group, name: str) -> DemoTrajectory:
    for key in ("states", "actions"):
        if key not in group:
            raise LearnDataError(f"{name} has no {key!r}: it cannot start episodes")
    metadata = json.loads(attr_text(group.attrs.get("metadata", "{}")))
    if not metadata.get("sim_config"):
        raise LearnDataError(f"{name} recorded no sim_config: its states cannot be restored")
    states = np.asarray(group["states"][()], dtype=np.float64)
    controller = (
        np.asarray(group["controller_states"][()], dtype=np.float64)
        if "controller_states" in group
        else np.zeros((len(states), 0))
    )
    return DemoTrajectory(
        name=name,
        states=states,
        controller_states=controller.reshape(len(states), -1),
        actions=np.asarray(group["actions"][()], dtype=np.float64),
        model_xml=attr_text(group.attrs.get("model_file", "")),
        # as it rebuilds now: keys added since take the values they had then
        sim_config=SimConfig.from_recorded(metadata["sim_config"]).model_dump(mode="json"),
        reset_seed=metadata.get("reset_seed"),
    )
