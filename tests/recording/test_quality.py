"""The quality metrics an episode carries (issue 29): each one moves with what it measures and
stays still otherwise, on hand paths built to show it, and bad recordings give None, never NaN."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from crowdteleop.recording.quality import (
    EpisodeMetrics,
    MotionInputs,
    QualityThresholds,
    better_than,
    clutch_reanchors,
    episode_metrics,
    motion_of,
    quality_flags,
    quality_score,
    setback_metrics,
    table_metrics,
)

HZ = 20.0
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def reach(seconds: float = 3.0, distance_m: float = 0.3) -> np.ndarray:
    """A minimum-jerk reach along x: what a smooth, practised hand does."""
    t = np.linspace(0.0, 1.0, int(seconds * HZ))
    s = 10 * t**3 - 15 * t**4 + 6 * t**5
    return np.column_stack([s * distance_m, np.zeros_like(s), np.zeros_like(s)])


def motion(
    positions: np.ndarray,
    stages: list[str] | None = None,
    gripper: list[bool] | None = None,
    engaged: list[bool] | None = None,
    joints: np.ndarray | None = None,
) -> MotionInputs:
    n = len(positions)
    pose = np.column_stack([positions, np.tile(IDENTITY, (n, 1))])
    states = np.zeros((n, 3)) if joints is None else np.column_stack([np.zeros(n), joints])
    return MotionInputs(
        dt_s=1 / HZ,
        hand_pose=pose,
        stages=stages,
        engaged=engaged if engaged is not None else [True] * n,
        gripper_closed=gripper if gripper is not None else [False] * n,
        states=states,
        arm_state_index=[1, 2] if joints is not None else None,
        arm_limits_rad=np.array([[-1.0, 1.0], [-2.0, 2.0]]) if joints is not None else None,
    )


def still(seconds: float, at: np.ndarray) -> np.ndarray:
    return np.tile(at, (int(seconds * HZ), 1))


def test_a_smooth_reach_is_straight_smooth_and_never_idle():
    metrics = episode_metrics(motion(reach()), {})
    assert metrics.completion_time_s == pytest.approx(3.0)
    assert metrics.path_length_m == pytest.approx(0.3, abs=1e-3)
    assert metrics.path_ratio == pytest.approx(1.0, abs=1e-3)
    assert metrics.idle_between_s == 0.0 and metrics.longest_pause_s == 0.0
    assert metrics.idle_start_s is not None and metrics.idle_start_s < 0.3  # it sets off slowly
    assert metrics.clutch_reanchors == 0 and metrics.gripper_changes == 0


def test_tremor_raises_jerk_and_lowers_smoothness():
    smooth = reach()
    rng = np.random.default_rng(0)
    shaky = smooth + rng.normal(0.0, 0.002, smooth.shape)  # 2 mm of tremor
    calm, trembling = episode_metrics(motion(smooth), {}), episode_metrics(motion(shaky), {})
    assert trembling.jerk_rms_m_s3 > 10 * calm.jerk_rms_m_s3
    assert trembling.sparc < calm.sparc <= 0.0, "spectral arc length: nearer 0 is smoother"


def test_a_ten_second_pause_is_measured_and_placed_in_its_stage():
    there = reach()
    path = np.vstack([still(2.0, there[0]), there, still(10.0, there[-1]), there[::-1]])
    stages = ["reach"] * (40 + len(there)) + ["grasp"] * 200 + ["lift"] * len(there)
    metrics = episode_metrics(motion(path, stages=stages), {})
    assert metrics.idle_start_s == pytest.approx(2.0, abs=0.3)
    assert metrics.longest_pause_s == pytest.approx(10.0, abs=0.6)
    assert metrics.longest_pause_stage == "grasp"
    assert metrics.idle_between_s >= metrics.longest_pause_s
    idle_s = metrics.idle_start_s + metrics.idle_between_s + metrics.idle_end_s
    assert metrics.idle_fraction == pytest.approx(idle_s / metrics.completion_time_s, abs=1e-3)
    assert metrics.idle_fraction > 12 / 18


def test_a_detour_raises_the_path_ratio_and_going_there_and_back_does_not():
    there = reach()
    n = len(there)
    back_again = np.vstack([there, there[::-1]])
    stages = ["reach"] * n + ["lift"] * n  # the waypoints: start, the grasp, the end
    straight = episode_metrics(motion(back_again, stages=stages), {})
    assert straight.path_ratio == pytest.approx(1.0, abs=1e-2)
    sideways = np.column_stack([np.zeros(n), there[:, 0], np.zeros(n)])
    across = sideways[-1] + (there[-1] - sideways[-1]) * (there[:, :1] / there[-1, 0])
    detour = np.vstack([sideways, across, there[::-1]])
    stages = ["reach"] * (2 * n) + ["lift"] * n
    metrics = episode_metrics(motion(detour, stages=stages), {})
    assert metrics.path_ratio == pytest.approx((0.3 + 0.3 * math.sqrt(2) + 0.3) / 0.6, abs=0.02)


def test_clutch_reanchors_count_each_take_after_the_first():
    assert clutch_reanchors([False, True, True, False, False, True, False, True]) == 2
    assert clutch_reanchors([True] * 5) == 0
    assert clutch_reanchors([False] * 5) == 0


def test_quick_gripper_reversals_are_chatter_and_one_deliberate_grasp_is_not():
    n = len(reach())
    once = [False] * 30 + [True] * (n - 30)
    hesitant = [False] * 30 + [True, True, False, False, True, False] + [True] * (n - 36)
    assert episode_metrics(motion(reach(), gripper=once), {}).gripper_chatter == 0
    metrics = episode_metrics(motion(reach(), gripper=hesitant), {})
    assert metrics.gripper_changes == 5 and metrics.gripper_chatter == 4


def test_time_near_a_joint_limit_is_the_share_of_steps_there():
    n = len(reach())
    joints = np.zeros((n, 2))
    joints[: n // 4, 0] = 0.97  # within 5 % of the range (0.1 rad) of its upper limit
    metrics = episode_metrics(motion(reach(), joints=joints), {})
    assert metrics.joint_limit_fraction == pytest.approx((n // 4) / n, abs=1e-3)


def test_the_network_figures_come_from_the_sessions_telemetry():
    telemetry = {
        "latency_p50_ms": 48.0,
        "latency_p95_ms": 90.5,
        "rtt_jitter_ms": 3.2,
        "loss_fraction": 0.01,
        "episode_video_stalls": 2,
        "unrelated": "kept out",
    }
    metrics = episode_metrics(motion(reach()), telemetry, resets_before=3)
    assert (metrics.latency_p50_ms, metrics.latency_p95_ms) == (48.0, 90.5)
    assert (metrics.video_stalls, metrics.resets_before) == (2, 3)
    assert episode_metrics(motion(reach()), {}).latency_p50_ms is None, "no link: unknown"
    unreported = episode_metrics(motion(reach()), {"latency_p50_ms": 0.0, "latency_p95_ms": 0.0})
    assert unreported.latency_p50_ms is None, "no client reported a latency: unknown, not 0"


def test_nan_in_the_recording_gives_unknown_metrics_not_nan():
    path = reach()
    path[10] = np.nan
    metrics = episode_metrics(motion(path), {})
    dumped = metrics.model_dump()
    assert all(not (isinstance(v, float) and math.isnan(v)) for v in dumped.values())
    assert metrics.path_length_m is None and metrics.completion_time_s == pytest.approx(3.0)
    assert EpisodeMetrics.model_validate_json(metrics.model_dump_json()) == metrics


def test_an_episode_without_labels_has_no_hand_metrics():
    inputs = motion(reach())
    unlabelled = MotionInputs(
        inputs.dt_s, None, None, inputs.engaged, inputs.gripper_closed, inputs.states
    )
    metrics = episode_metrics(unlabelled, {})
    assert metrics.path_length_m is None and metrics.sparc is None
    assert metrics.clutch_reanchors == 0, "the commands still say what they can"


def test_table_touches_count_once_however_a_sliding_finger_flickers():
    touching = [False] * 10 + [True, True, False, True] + [False] * 10 + [True] * 6
    assert table_metrics(touching, 1 / HZ) == {"table_contacts": 2, "table_contact_s": 0.45}
    assert table_metrics([False] * 20, 1 / HZ) == {"table_contacts": 0, "table_contact_s": 0.0}


def recorded_touching_the_table_once() -> SimpleNamespace:
    """An episode's arrays as the metrics read them: one of three steps touching the table."""
    table = {"robot_part": "finger", "object": "table", "intensity": 0.4}
    return SimpleNamespace(
        labels=None,
        commands=[{"engaged": True}] * 3,
        states=np.zeros((3, 3)),
        contacts=[[], [table], []],
    )


def test_table_metrics_come_only_from_recordings_whose_contacts_could_name_the_table():
    episode = recorded_touching_the_table_once()
    named = motion_of(episode, {"contact_objects": ["cube", "table"]})
    assert episode_metrics(named, {}).table_contacts == 1
    older = motion_of(episode, {})  # recorded before the table's contacts were
    assert episode_metrics(older, {}).table_contacts is None


def test_a_drop_is_a_setback_and_a_flickering_stage_test_is_not():
    dropped = ["reach"] * 40 + ["grasped"] * 30 + ["reach"] * 20 + ["grasped"] * 30 + ["done"] * 5
    assert setback_metrics(dropped, 1 / HZ) == {
        "setbacks": 1,
        "first_setback": "grasped -> reach at 3.5 s",
    }
    flicker = ["reach"] * 40 + ["grasped"] * 30 + ["reach"] * 2 + ["grasped"] * 30
    assert setback_metrics(flicker, 1 / HZ) == {"setbacks": 0, "first_setback": None}


def test_flags_say_why_in_words_and_only_past_the_campaigns_thresholds():
    metrics = EpisodeMetrics(
        completion_time_s=30.0,
        longest_pause_s=11.0,
        longest_pause_stage="grasped",
        path_ratio=2.4,
        gripper_changes=5,
        gripper_chatter=4,
        table_contacts=2,
        table_contact_s=0.8,
        video_stalls=0,
    )
    reasons = [f.reason for f in quality_flags(metrics, QualityThresholds())]
    assert reasons == [
        "idle 11 s in the 'grasped' stage",
        "a detour: the hand travelled 2.4 times the straight path",
        "a hesitant grasp: the gripper changed 5 times, 4 of them within 1 s of the last",
        "pressed into the table: 2 times, 0.8 s in all",
    ]
    lenient = QualityThresholds(
        longest_pause_s=20, path_ratio=3, gripper_chatter=5, table_contact_s=1.0
    )
    assert quality_flags(metrics, lenient) == []


def test_the_score_is_the_mean_percentile_over_the_scored_metrics():
    assert better_than(2.0, [1.0, 2.0, 3.0, 4.0], direction=-1) == pytest.approx(2.5 / 4)
    assert better_than(2.0, [1.0, 2.0, 3.0, 4.0], direction=1) == pytest.approx(1.5 / 4)
    campaign = {"completion_time_s": [3.0, 5.0, 8.0, 13.0], "sparc": [-4.0, -3.0, -2.0, -1.0]}
    fastest = EpisodeMetrics(completion_time_s=2.0, sparc=-0.5)
    slowest = EpisodeMetrics(completion_time_s=20.0, sparc=-5.0)
    assert quality_score(fastest, campaign) == 100.0 and quality_score(slowest, campaign) == 0.0
    assert quality_score(fastest, {}) is None, "nothing to compare with"


def test_the_docs_describe_every_metric_as_the_model_does():
    text = (Path(__file__).parents[2] / "docs" / "quality.md").read_text()
    for name, field in EpisodeMetrics.model_fields.items():
        assert f"| `{name}` | {field.description} |" in text, f"docs/quality.md: {name}"
