"""Episode tracking (crowdteleop.teleop.episode): started by the clutch, ended by held success,
the time limit or a disconnect."""

from __future__ import annotations


def _step(index: int, success: bool = False):
    import numpy as np

    from crowdteleop.recording.episode_file import StepRecord

    return StepRecord(
        index=index,
        state=np.zeros(5),
        action=np.zeros(2),
        command={"seq": index},
        server_time=0.0,
        step_duration_s=0.001,
        reward=float(success),
        success=success,
        contacts=[],
    )


def _tracker(tmp_path, time_limit_s: float = 1.0):
    from crowdteleop.recording.metadata import EpisodeMetadata
    from crowdteleop.teleop.episode import EpisodeTracker

    return EpisodeTracker(
        control_dt=0.05,
        time_limit_s=time_limit_s,
        success_hold_steps=3,
        recordings=tmp_path,
        metadata=EpisodeMetadata(session_id="units"),
    )


def test_an_episode_starts_with_the_clutch_and_ends_after_success_is_held(tmp_path):
    tracker = _tracker(tmp_path)
    assert not tracker.maybe_start(engaged=False) and tracker.state == "ready"
    assert tracker.maybe_start(engaged=True) and tracker.state == "running"
    outcomes = [tracker.record(_step(i, success=i >= 2)) for i in range(5)]
    assert outcomes == [None, None, None, None, "success"], "held for 3 steps, as configured"
    finished = tracker.end("success")
    assert finished.steps == 5 and tracker.successes == 1 and tracker.state == "ready"
    assert finished.recorder.finalize(finished.outcome).exists()


def test_an_episode_times_out_and_a_disconnect_ends_it(tmp_path):
    tracker = _tracker(tmp_path, time_limit_s=0.2)
    tracker.maybe_start(engaged=True)
    assert [tracker.record(_step(i)) for i in range(4)] == [None, None, None, "timeout"]
    tracker.end("timeout")
    tracker.maybe_start(engaged=True)
    tracker.record(_step(0))
    finished = tracker.end("disconnect")
    assert finished.outcome == "disconnect" and finished.number == 2
    assert tracker.end("reset") is None, "nothing runs: nothing to end"


def test_each_episode_knows_how_many_ended_otherwise_since_the_last_success(tmp_path):
    """What the quality metric `resets_before` reads (docs/quality.md)."""
    tracker = _tracker(tmp_path)
    befores = []
    for outcome in ("reset", "timeout", "success", "success", "reset"):
        tracker.maybe_start(engaged=True)
        tracker.record(_step(0))
        befores.append(tracker.end(outcome).resets_before)
    assert befores == [0, 1, 2, 0, 0]


def test_step_labels_read_the_simulation_and_step_record_keeps_them(tmp_path):
    from types import SimpleNamespace

    import numpy as np

    from crowdteleop.recording.episode_file import StepLabels, read_episode
    from crowdteleop.sim.types import Pose, TaskProgress
    from crowdteleop.teleop.episode import step_record

    def pose(x: float) -> Pose:
        return Pose(np.array([x, 0.0, 1.0]), np.array([0.0, 0.0, 0.0, 1.0]))

    sim = SimpleNamespace(  # what StepLabels.read asks of a Simulation
        progress=lambda: TaskProgress("grasped", "...", 1, 2, "Can/target"),
        robot_state=lambda: SimpleNamespace(end_effector=pose(0.5)),
        object_poses=lambda: {"Can": pose(0.1), "Can/target": pose(0.2)},
    )
    labels = StepLabels.read(sim)
    result = SimpleNamespace(reward=0.0, success=False, contacts=[])
    step = SimpleNamespace(action=np.zeros(2), result=result)
    tracker = _tracker(tmp_path)
    tracker.maybe_start(engaged=True)
    tracker.record(step_record(0, np.zeros(5), step, {"seq": 0}, 0.0, 0.001, labels))
    tracker.record(step_record(1, np.zeros(5), step, {"seq": 1}, 0.0, 0.001))  # unlabelled
    finished = tracker.end("reset")
    recorded = read_episode(finished.recorder.finalize(finished.outcome)).labels
    assert recorded.stage == ["grasped", ""] and recorded.relative_to == ["Can/target", ""]
    np.testing.assert_array_equal(recorded.hand_pose[0], [0.5, 0, 1, 0, 0, 0, 1])
    assert np.isnan(recorded.hand_pose[1]).all()
    np.testing.assert_array_equal(recorded.object_poses["Can/target"][0], [0.2, 0, 1, 0, 0, 0, 1])
