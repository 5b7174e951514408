"""What a worker is told after a counted demonstration (issue 29, item 3; docs/quality.md):
each figure beside the study's middle, and one tip: a flag's first, else the weakest figure's
when below the middle, else praise."""

from __future__ import annotations

from crowdteleop.coord.service.feedback import WELL_DONE, worker_feedback
from crowdteleop.recording.quality import EpisodeMetrics, QualityThresholds, quality_flags

STUDY = {
    "completion_time_s": [4.0, 6.0, 8.0, 10.0, 12.0],
    "idle_fraction": [0.05, 0.1, 0.15, 0.2, 0.25],
    "sparc": [-4.0, -3.5, -3.0, -2.5, -2.0],
}


def feedback_for(**metrics):
    measured = EpisodeMetrics(**metrics)
    flags = quality_flags(measured, QualityThresholds())
    return worker_feedback(3, measured, STUDY, 40.0, flags)


def test_the_figures_stand_beside_the_studys_middle():
    told = feedback_for(completion_time_s=5.0, idle_fraction=0.12, sparc=-2.2)
    assert (told.type, told.episode, told.score) == ("feedback", 3, 40.0)
    assert (told.time_s, told.median_time_s) == (5.0, 8.0)
    assert (told.idle_percent, told.median_idle_percent) == (12.0, 15.0)
    assert told.smoother_than_percent == 80.0
    assert told.tip == WELL_DONE, "better than the middle on every figure"


def test_a_flag_gives_the_tip_in_the_workers_words():
    told = feedback_for(completion_time_s=9.0, longest_pause_s=7.4, longest_pause_stage="reach")
    assert (
        told.tip
        == "Plan your next move while the arm is still moving: you paused 7 s in one place."
    )
    dropped = feedback_for(
        completion_time_s=9.0, setbacks=1, first_setback="grasped -> reach at 4.0 s"
    )
    assert dropped.tip.startswith("Keep the gripper closed until the object is where it belongs")


def test_without_a_flag_the_weakest_figure_below_the_middle_is_the_tip():
    slow = feedback_for(completion_time_s=14.0, idle_fraction=0.1, sparc=-2.2)
    assert slow.tip == "You can go faster: this took 14 s, the study's middle is 8 s."
    jolty = feedback_for(completion_time_s=5.0, idle_fraction=0.1, sparc=-4.5)
    assert jolty.tip.startswith("Move your device smoothly")
    alone = worker_feedback(1, EpisodeMetrics(completion_time_s=5.0), {}, None, [])
    assert alone.median_time_s is None and alone.tip == WELL_DONE, "nothing to compare with yet"
