"""What a worker is told after each counted demonstration (issue 29, item 3): its time, how much
of it was idle and how smooth it was, each against the study's own median, and one concrete
tip, chosen from what stood out most (a flag first, else the figure furthest below the
study's middle). Workers told how to do better improve faster (DQAF, 2026)."""

from __future__ import annotations

import statistics
from collections.abc import Mapping, Sequence

from crowdteleop.recording.quality import (
    SCORED_METRICS,
    EpisodeMetrics,
    QualityFlag,
    better_than,
)
from crowdteleop.teleop.protocol import EpisodeFeedback

WELL_DONE = "Well done: quicker and smoother than most. Keep going like this."


def _median(distributions: Mapping[str, Sequence[float]], name: str) -> float | None:
    values = distributions.get(name)
    return float(statistics.median(values)) if values else None


def _percent(value: float | None) -> float | None:
    return None if value is None else round(100 * value, 1)


def worker_feedback(
    episode: int,
    metrics: EpisodeMetrics,
    distributions: Mapping[str, Sequence[float]],
    score: float | None,
    flags: Sequence[QualityFlag],
) -> EpisodeFeedback:
    """The feedback for a demonstration scored `score` against `distributions` (each scored
    metric's values over the study's successful demonstrations of the task, ascending)."""
    sparc = distributions.get("sparc")
    smoother = (
        round(100 * better_than(metrics.sparc, sparc, SCORED_METRICS["sparc"]), 1)
        if metrics.sparc is not None and sparc
        else None
    )
    return EpisodeFeedback(
        episode=episode,
        score=score,
        time_s=metrics.completion_time_s,
        median_time_s=_median(distributions, "completion_time_s"),
        idle_percent=_percent(metrics.idle_fraction),
        median_idle_percent=_percent(_median(distributions, "idle_fraction")),
        smoother_than_percent=smoother,
        tip=tip(metrics, distributions, flags),
    )


FLAG_TIPS = {  # most important first
    "setbacks": "Keep the gripper closed until the object is where it belongs: this time it "
    "slipped, and the task went back a step.",
    "longest_pause_s": "Plan your next move while the arm is still moving: you paused "
    "{longest_pause_s:.0f} s in one place.",
    "gripper_chatter": "Close the gripper once, when the fingers surround the object, and keep "
    "it closed.",
    "path_ratio": "Head straight for the object: your hand travelled {path_ratio:.1f} times the "
    "direct path.",
    "idle_start_s": "Start moving as soon as the robot appears: you waited {idle_start_s:.0f} s.",
    "clutch_reanchors": "Hold the clutch through a whole move: each release pauses the arm.",
    "latency_p95_ms": "Your connection was slow: move a little slower so the video keeps up.",
    "video_stalls": "Your video stalled: move a little slower so it keeps up.",
}


def tip(
    metrics: EpisodeMetrics,
    distributions: Mapping[str, Sequence[float]],
    flags: Sequence[QualityFlag],
) -> str:
    """One thing to do better: the most important flag's (`FLAG_TIPS` in order), else the
    weakest of time, idle and smoothness if it is below the study's middle, else praise."""
    flagged = {flag.metric for flag in flags}
    for metric, text in FLAG_TIPS.items():  # in order of what matters most
        if metric in flagged:
            return text.format(**metrics.model_dump())
    weakest = _weakest(metrics, distributions)
    if weakest == "completion_time_s":
        median = _median(distributions, "completion_time_s")
        return (
            f"You can go faster: this took {metrics.completion_time_s:.0f} s, the study's "
            f"middle is {median:.0f} s."
        )
    if weakest == "idle_fraction":
        return "Keep the arm moving: it stood still for a good part of this demonstration."
    if weakest == "sparc":
        return "Move your device smoothly, without jolts: steady moves teach the robot best."
    return WELL_DONE


def _weakest(metrics: EpisodeMetrics, distributions: Mapping[str, Sequence[float]]) -> str | None:
    """The one of time, idle and smoothness this demonstration ranks lowest on, if below half."""
    ranks = {
        name: better_than(value, values, SCORED_METRICS[name])
        for name in ("completion_time_s", "idle_fraction", "sparc")
        if (value := getattr(metrics, name)) is not None and (values := distributions.get(name))
    }
    if not ranks:
        return None
    name = min(ranks, key=lambda n: ranks[n])
    return name if ranks[name] < 0.5 else None
