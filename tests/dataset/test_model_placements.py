"""robosuite places some bodies in the model, not the state (Door's door, PickPlace's visual
stand-ins): the model file recorded with an episode must put them where that episode's reset
did, or robosuite's own playback shows another scene with the same states."""

from __future__ import annotations

import numpy as np
import pytest

from crowdteleop.dataset.robosuite_replay import RobosuiteReplayer
from crowdteleop.provenance.env_args import EnvArgs
from crowdteleop.recording.metadata import robosuite_version
from crowdteleop.sim import SimConfig, make_simulation
from crowdteleop.sim.mjcf import same_model


@pytest.mark.parametrize(
    ("task", "body"), [("door", "Door_main"), ("pick-place-can", "VisualCan_main")]
)
def test_the_model_file_puts_placed_bodies_where_the_reset_did(task, body):
    config = SimConfig(task=task, robot="Panda", action_mode="osc-pose")
    sim = make_simulation(config)
    try:
        loaded = sim.mjcf_xml()
        sim.reset(seed=3)
        placed = sim.mjcf_xml()
        ours = sim.object_poses()
        positions, _ = sim.body_placements()
        state = sim.get_state()
    finally:
        sim.close()
    assert placed != loaded and same_model(placed, loaded), "the same model, placed anew"
    replayer = RobosuiteReplayer(EnvArgs.of(config, robosuite_version()), placed)
    try:
        plain = replayer.env
        plain.sim.set_state_from_flattened(state)
        plain.sim.forward()
        theirs = plain.sim.model.body_pos[plain.sim.model.body_name2id(body)]
        assert np.allclose(theirs, positions[plain.sim.model.body_name2id(body)], atol=1e-9)
        if task == "door":
            handle = plain.sim.data.site_xpos[plain.sim.model.site_name2id("Door_handle")]
            assert np.allclose(handle, ours["Door/handle"].position, atol=1e-6)
    finally:
        replayer.close()
