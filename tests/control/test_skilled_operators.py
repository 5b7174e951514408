"""Synthetic workers of known skill: each level's traits show in the episodes it records (lift,
Panda, OSC, in-process), and a seed still drives one exact episode."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from crowdteleop.control.scripted import OperatorStyle, ScriptedOperator, run_episode
from crowdteleop.control.scripted.skills import SKILLS, style_for
from crowdteleop.dataset.scripted import ScriptedEpisode, record_scripted_episode, scripted_rig
from crowdteleop.recording.episode_file import read_episode, read_metadata
from crowdteleop.recording.quality import (
    EpisodeMetrics,
    QualityFlag,
    QualityThresholds,
    quality_flags,
)
from crowdteleop.vocab import SKILL_NAMES

SEEDS = range(4)
TIME_LIMIT_S = 40.0


@pytest.fixture(scope="module")
def rig():
    with scripted_rig("lift", "osc", robot="Panda") as rig:
        yield rig


@pytest.fixture(scope="module")
def episodes(rig, tmp_path_factory):
    """Expert and novice episodes on the same seeds: {level: [(episode, quality), ...]}."""
    directory = tmp_path_factory.mktemp("skilled")
    recorded = {}
    for level in ("expert", "novice"):
        recorded[level] = [
            _quality(record(rig, directory, f"{level}-{seed}", seed, SKILLS[level]))
            for seed in SEEDS
        ]
    return recorded


def record(rig, directory, name, seed, style) -> ScriptedEpisode:
    return record_scripted_episode(
        rig, directory, name, seed, style=style, time_limit_s=TIME_LIMIT_S
    )


def _quality(episode: ScriptedEpisode) -> tuple[ScriptedEpisode, dict]:
    return episode, read_metadata(episode.path)["quality"]


def test_every_level_is_a_valid_style_and_the_vocabulary_names_them_all():
    assert set(SKILLS) == set(SKILL_NAMES)
    assert all(isinstance(style, OperatorStyle) for style in SKILLS.values())


def test_experts_succeed_and_novices_mostly_do(episodes):
    assert all(episode.outcome == "success" for episode, _ in episodes["expert"])
    novice = [episode.outcome == "success" for episode, _ in episodes["novice"]]
    assert np.mean(novice) >= 0.6


def test_novices_are_slower_and_shakier_than_experts_on_the_same_seeds(episodes):
    def median(level: str, metric: str) -> float:
        return float(np.median([quality[metric] for _, quality in episodes[level]]))

    assert median("novice", "completion_time_s") > 2 * median("expert", "completion_time_s")
    assert median("novice", "jerk_rms_m_s3") > median("expert", "jerk_rms_m_s3")


def test_novices_hesitate_over_grasps(episodes):
    """Gripper chatter: closed and reopened within a second before the grasp holds."""
    assert all(quality["gripper_chatter"] == 0 for _, quality in episodes["expert"])
    assert any(
        novice["gripper_changes"] > expert["gripper_changes"] and novice["gripper_chatter"] > 0
        for (_, novice), (_, expert) in zip(episodes["novice"], episodes["expert"], strict=True)
    )


def test_a_drop_while_carrying_loses_the_cube(rig, tmp_path):
    episode = record(rig, tmp_path, "drop", 0, OperatorStyle(drop_probability=1.0))
    assert episode.outcome != "success"
    assert read_metadata(episode.path)["quality"]["gripper_changes"] >= 3  # close, open, close
    labels = read_episode(episode.path).labels
    assert labels is not None
    assert "grasped" in labels.stage
    height = labels.object_poses["cube"][:, 2]
    assert np.nanmax(height) > height[0] + 0.02  # it was lifted,
    assert height[-1] < height[0] + 0.01  # then fell back on the table


def hand_targets(rig, style, seed):
    """(stage, waypoint position, commanded hand position, arm's hand position) per step."""
    operator = ScriptedOperator(rig.sim, rig.control.mapping, style=style, seed=seed)
    rows = []

    def on_step(step) -> None:
        waypoint = operator.waypoint
        if waypoint is not None:
            hand = rig.sim.robot_state().end_effector.position
            rows.append((waypoint.label, waypoint.pose.position, step.target.position, hand))

    result = run_episode(rig.teleop, operator, seed, time_limit_s=TIME_LIMIT_S, on_step=on_step)
    return result, rows


def test_overshoot_passes_the_waypoint_then_corrects(rig):
    result, rows = hand_targets(rig, OperatorStyle(overshoot_fraction=0.3), seed=2)
    assert result.success
    hover = [row for row in rows if row[0] == "hover"]
    goal, start = hover[0][1], hover[0][3]
    length = float(np.linalg.norm(goal - start))
    direction = (goal - start) / length
    past = max(float(np.dot(target - goal, direction)) for _, _, target, _ in hover)
    # aimed past the mark (less than 30 %: hover is lower than the start, and an overshoot
    # never aims below its waypoint), then back to it
    assert 0.1 * length < past <= 0.3 * length + 1e-9
    assert np.linalg.norm(hover[-1][2] - goal) < 1e-6
    descend = [row for row in rows if row[0] == "descend"]
    assert min(target[2] for _, _, target, _ in descend) >= descend[0][1][2] - 1e-9


def _longest_still_s(rows, dt: float) -> float:
    """The longest time the commanded hand stayed put (s)."""
    longest = run = 0
    for before, after in itertools.pairwise(rows):
        run = run + 1 if np.array_equal(before[2], after[2]) else 0
        longest = max(longest, run)
    return longest * dt


@pytest.mark.parametrize(
    ("style", "delay_s"),
    [
        (OperatorStyle(reaction_s=0.5), 0.5),
        (OperatorStyle(idle_probability=1.0, idle_s=(2.0, 2.0)), 2.0),
    ],
    ids=["reaction", "idle"],
)
def test_reaction_and_idle_time_add_their_delay_per_waypoint(rig, style, delay_s):
    """Lift's plan has five waypoints; success comes during the last. The hand stays put for
    the whole delay (the Panda's OSC keeps the arm itself trembling by a few mm at rest, so
    the recorded hand path does not show it as idle)."""
    steady, _ = hand_targets(rig, None, seed=3)
    slow, rows = hand_targets(rig, style, seed=3)
    assert steady.success and slow.success
    assert slow.sim_seconds - steady.sim_seconds == pytest.approx(5 * delay_s, abs=0.5)
    assert _longest_still_s(rows, rig.sim.control_dt) >= delay_s - 0.1


def test_a_seed_and_a_style_drive_one_exact_episode(rig):
    def commands(seed: int) -> list[tuple]:
        operator = ScriptedOperator(rig.sim, rig.control.mapping, style=SKILLS["novice"], seed=seed)
        sent = []
        run_episode(
            rig.teleop,
            operator,
            seed,
            time_limit_s=8.0,
            on_step=lambda step: sent.append(
                (*step.command.position, *step.command.quaternion, step.command.gripper_closed)
            ),
        )
        return sent

    first = commands(5)
    assert first == commands(5)
    assert first != commands(6)


@pytest.mark.parametrize(
    ("fault", "metric", "words"),
    [
        ("idle", "longest_pause_s", "idle 10 s"),
        ("detour", "path_ratio", "a detour"),
        ("press", "table_contact_s", "pressed into the table: once"),
    ],
)
def test_an_injected_fault_is_flagged_by_its_name_and_nothing_else(
    rig, tmp_path, fault, metric, words
):
    """A steady operator told to make one fault: the quality flags name that fault alone (an
    arm trembling while the hand waits is no detour)."""
    for seed in (1, 2):
        clean = record(rig, tmp_path, f"clean-{seed}", seed, style_for("expert"))
        faulty = record(rig, tmp_path, f"{fault}-{seed}", seed, style_for("expert", fault))
        assert clean.outcome == faulty.outcome == "success"
        assert _flags(clean) == []
        flags = _flags(faulty)
        assert [flag.metric for flag in flags] == [metric]
        assert words in flags[0].reason


def test_the_table_is_touched_only_by_an_operator_told_to_press_into_it(rig, tmp_path):
    """Every step's contacts are recorded with the table among them, so the touch is counted
    where it happened; a clean grasp of the cube never brushes the table."""
    clean = read_metadata(record(rig, tmp_path, "clean", 3, style_for("novice")).path)
    pressed = read_metadata(record(rig, tmp_path, "press", 3, style_for("novice", "press")).path)
    assert "table" in clean["contact_objects"]
    assert (clean["quality"]["table_contacts"], clean["quality"]["table_contact_s"]) == (0, 0.0)
    assert pressed["quality"]["table_contacts"] == 1
    assert pressed["quality"]["table_contact_s"] >= 0.3


def test_an_injected_drop_happens_once_on_the_first_carrying_leg(rig, tmp_path):
    episode = record(rig, tmp_path, "drop", 0, style_for("expert", "drop"))
    assert episode.outcome != "success"
    assert read_metadata(episode.path)["quality"]["gripper_changes"] == 3  # close, open, close


def _flags(episode: ScriptedEpisode) -> list[QualityFlag]:
    metrics = EpisodeMetrics.model_validate(read_metadata(episode.path)["quality"])
    return quality_flags(metrics, QualityThresholds())
