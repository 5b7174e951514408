"""Demonstration-guided resets (the paper's Appendix): with probability p an episode starts
from a demonstration's state, the demo drawn uniformly and then its step uniformly, and the
state is restored exactly: the next recorded action reproduces the next recorded state."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from crowdteleop.learn.data import LearnDataError
from crowdteleop.learn.demo_states import DemoStates, DemoTrajectory, StartState, load_demo_states
from crowdteleop.learn.envs import EnvSettings, make_env


@pytest.fixture(scope="module")
def demos(lift_dataset):
    return load_demo_states(lift_dataset)


def trajectory(name, steps):
    return DemoTrajectory(
        name, np.zeros((steps, 3)), np.zeros((steps, 0)), np.zeros((steps, 2)), "", {}, None
    )


def test_demos_are_drawn_uniformly_whatever_their_length():
    draws = DemoStates([trajectory("short", 10), trajectory("long", 1000)])
    rng = np.random.default_rng(0)
    picks = [draws.draw(rng) for _ in range(4000)]
    counts = np.bincount([p.demo for p in picks], minlength=2)
    assert stats.chisquare(counts).pvalue > 0.001, counts
    short_steps = np.bincount([p.step for p in picks if p.demo == 0], minlength=10)
    assert len(short_steps) == 10, "steps stay inside the demo"
    assert stats.chisquare(short_steps).pvalue > 0.001, short_steps


def test_resets_start_in_a_demo_with_probability_p(demos):
    env = make_env(EnvSettings(sim_config=demos.sim_config, demo_reset_p=0.7), demos)
    try:
        env.reset(seed=0)
        starts = [env.reset()[1]["start"] for _ in range(600)]
    finally:
        env.close()
    share = starts.count("demo") / len(starts)
    assert stats.binomtest(starts.count("demo"), len(starts), 0.7).pvalue > 0.001, share


def test_p_zero_never_and_p_one_always_starts_in_a_demo(demos):
    for p, expected in ((0.0, "normal"), (1.0, "demo")):
        env = make_env(EnvSettings(sim_config=demos.sim_config, demo_reset_p=p), demos)
        try:
            env.reset(seed=0)
            assert {env.reset()[1]["start"] for _ in range(30)} == {expected}
        finally:
            env.close()


def test_a_restored_state_is_exact_and_replays_the_next_step_exactly(demos):
    env = make_env(EnvSettings(sim_config=demos.sim_config), demos)
    try:
        for index, demo in enumerate(demos.demos):
            for step in (0, len(demo) // 2, len(demo) - 2):
                env.reset(options={"start": StartState(index, step)})
                np.testing.assert_array_equal(env.sim.get_state(), demo.states[step])
                np.testing.assert_array_equal(
                    env.sim.controller_state(), demo.controller_states[step]
                )
                env.sim.step(demo.actions[step])
                np.testing.assert_array_equal(env.sim.get_state(), demo.states[step + 1])
    finally:
        env.close()


def test_asking_for_more_demos_than_the_dataset_holds_says_how_many_it_has(lift_dataset):
    with pytest.raises(LearnDataError, match="holds 3 demonstrations"):
        load_demo_states(lift_dataset, limit=50)


def test_demos_from_two_simulation_configs_are_refused():
    a, b = trajectory("a", 5), trajectory("b", 5)
    b = DemoTrajectory("b", b.states, b.controller_states, b.actions, "", {"task": "x"}, None)
    with pytest.raises(LearnDataError, match="different sim_configs"):
        DemoStates([a, b])


def test_demos_recorded_under_another_install_still_restore(demos):
    """A dataset trained on elsewhere: its model_file names the recording machine's paths."""
    import dataclasses

    moved = DemoStates(
        [
            dataclasses.replace(
                demo,
                model_xml=demo.model_xml.replace(
                    demo.model_xml.split("site-packages/")[0].split('file="')[-1],
                    "/home/someone/env/lib/python3.12/",
                ),
            )
            for demo in demos.demos
        ]
    )
    assert moved.demos[0].model_xml != demos.demos[0].model_xml
    env = make_env(EnvSettings(sim_config=moved.sim_config), moved)
    try:
        env.reset(options={"start": StartState(0, 5)})
        np.testing.assert_array_equal(env.sim.get_state(), moved.demos[0].states[5])
    finally:
        env.close()
    other = DemoStates(
        [dataclasses.replace(demos.demos[0], model_xml=demos.demos[0].model_xml + "<!-- -->")]
    )
    with pytest.raises(ValueError, match="no longer builds the model"):
        make_env(EnvSettings(sim_config=other.sim_config), other)
