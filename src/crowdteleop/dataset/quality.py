"""The demonstrations' quality in a dataset (docs/quality.md): each demo's metrics (as recorded,
or measured now for an episode recorded before metrics existed), its score among the
dataset's demos (one task: a robomimic dataset holds one environment), its flags; and the
filter keys a researcher trains on: ``quality_top_50``, ``quality_bottom_50`` (the
higher- and lower-scored halves, the middle demo of an odd count in neither) and
``quality_unflagged``."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from pydantic import ValidationError

from crowdteleop.recording.episode_file import Episode
from crowdteleop.recording.quality import (
    SCORED_METRICS,
    EpisodeMetrics,
    QualityFlag,
    QualityThresholds,
    measure,
    quality_flags,
    quality_score,
)


@dataclass(frozen=True)
class DemoQuality:
    metrics: EpisodeMetrics
    score: float | None  # 0-100 among the dataset's demos; None: nothing to compare
    flags: list[QualityFlag]


def recorded_metrics(episode: Episode) -> EpisodeMetrics:
    """The metrics the episode file carries, or measured from it now (older recordings)."""
    try:
        return EpisodeMetrics.model_validate(episode.metadata["quality"])
    except (KeyError, ValidationError):
        return measure(episode, episode.metadata)


def dataset_quality(
    episodes: Sequence[Episode], thresholds: QualityThresholds | None = None
) -> list[DemoQuality]:
    """Each episode's metrics, score against all of them, and flags."""
    thresholds = thresholds or QualityThresholds()
    metrics = [recorded_metrics(episode) for episode in episodes]
    distributions = {
        name: sorted(v for m in metrics if (v := getattr(m, name)) is not None)
        for name in SCORED_METRICS
    }
    return [
        DemoQuality(m, quality_score(m, distributions), quality_flags(m, thresholds))
        for m in metrics
    ]


def quality_masks(names: Sequence[str], qualities: Sequence[DemoQuality]) -> dict[str, list[str]]:
    """The filter keys, each in the dataset's demo order."""
    scored = [(n, q.score) for n, q in zip(names, qualities, strict=True) if q.score is not None]
    top, bottom = halves([n for n, _ in scored], [s for _, s in scored])
    order = set(top), set(bottom)
    return {
        "quality_top_50": [n for n in names if n in order[0]],
        "quality_bottom_50": [n for n in names if n in order[1]],
        "quality_unflagged": [n for n, q in zip(names, qualities, strict=True) if not q.flags],
    }


def halves(names: Sequence[str], scores: Sequence[float]) -> tuple[list[str], list[str]]:
    """The higher- and lower-scored halves, each in `names` order (ties go to the earlier
    name; the middle one of an odd count is in neither): the `_top_50`/`_bottom_50` keys."""
    ranked = [
        name
        for *_, name in sorted(
            (-s, i, n) for i, (n, s) in enumerate(zip(names, scores, strict=True))
        )
    ]
    half = len(ranked) // 2
    top, bottom = set(ranked[:half]), set(ranked[len(ranked) - half :])
    return [n for n in names if n in top], [n for n in names if n in bottom]
