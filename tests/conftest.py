"""Shared fixtures. Simulations are real (robosuite + MuJoCo, offscreen GL); each test closes
what it builds, since a robosuite environment holds about 1 GiB."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.sim.interface import Simulation


@pytest.fixture
def lift_sim() -> Iterator[Simulation]:
    sim = make_simulation(SimConfig(task="lift"))
    sim.reset(seed=0)
    yield sim
    sim.close()
