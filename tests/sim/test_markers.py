"""Markers: spheres drawn into frames only (a practice round's target), never into physics."""

from __future__ import annotations

import numpy as np
import pytest

from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.sim.types import Marker

GREEN = (0.15, 0.85, 0.25, 0.55)


@pytest.mark.parametrize("task", ["lift", "mujoco-lift"])
def test_a_marker_shows_in_the_frame_and_changes_nothing_else(task):
    sim = make_simulation(SimConfig(task=task))
    try:
        sim.reset(seed=0)
        state = sim.get_state()
        hand = sim.robot_state().end_effector.position
        x, y, z = (float(v) for v in hand + (0.04, 0.10, 0.06))
        marker = Marker((x, y, z), 0.03, GREEN)
        camera = sim.cameras[0] if "frontview" not in sim.cameras else "frontview"
        plain = sim.render(camera, 320, 240)
        marked = sim.render(camera, 320, 240, [marker])
        after = sim.render(camera, 320, 240)
        # The same pass with a marker too small to see: a frame with markers may be drawn
        # another way (one pass, see fastrender.compositor), so compare like with like.
        unmarked = sim.render(camera, 320, 240, [Marker((x, y, z), 1e-5, GREEN)])

        changed = np.abs(marked.astype(int) - unmarked.astype(int)).sum(axis=2) > 30
        assert 10 < changed.sum() < 3000, "a ball a few pixels across"
        green_gain = marked[changed][:, 1].astype(int) - unmarked[changed][:, 1]
        red_gain = marked[changed][:, 0].astype(int) - unmarked[changed][:, 0]
        assert np.mean(green_gain > red_gain) > 0.9, "what changed turned greener"
        np.testing.assert_array_equal(after, plain)  # no marked frame is served from a cache
        np.testing.assert_array_equal(sim.get_state(), state)  # physics never saw it
    finally:
        sim.close()
