"""Which episodes a dataset takes (`crowdteleop dataset build --filter`), by what reviewers
decided and how the demonstrations scored, and the review's filter keys in the dataset.

A reviewer's decision is read from beside the episode file (`recording.review`), so a build
needs the stored episodes only, never the coordinator's database. The filters:

- ``accepted``: only demonstrations a reviewer (or the campaign's score rule) accepted;
- ``not-rejected``: all but the rejected ones (undecided ones stay);
- ``unflagged``: only demonstrations no quality flag was raised on;
- ``score>=N``: only those scoring at least N (0-100) among the episodes the build chose.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from crowdteleop.dataset.files import DatasetError
from crowdteleop.dataset.quality import DemoQuality
from crowdteleop.recording.review import ReviewRecord, current_review

FILTER_FORMS = ("accepted", "not-rejected", "unflagged", "score>=N")
_SCORE = re.compile(r"^score\s*>=\s*(\d+(?:\.\d+)?)$")


@dataclass(frozen=True)
class DemoFilter:
    """One `--filter`: its text, and the least score for ``score>=N``."""

    text: str
    min_score: float | None = None

    def keeps(self, review: ReviewRecord | None, quality: DemoQuality) -> bool:
        decision = review.decision if review is not None else None
        if self.text == "accepted":
            return decision == "accepted"
        if self.text == "not-rejected":
            return decision != "rejected"
        if self.text == "unflagged":
            return not quality.flags
        assert self.min_score is not None
        return quality.score is not None and quality.score >= self.min_score


def parse_filter(text: str) -> DemoFilter:
    """A `--filter` as typed; anything else is a DatasetError naming the forms there are."""
    cleaned = text.strip().lower()
    if cleaned in ("accepted", "not-rejected", "unflagged"):
        return DemoFilter(cleaned)
    match = _SCORE.match(cleaned)
    if match is not None and float(match.group(1)) <= 100:
        return DemoFilter(cleaned, float(match.group(1)))
    raise DatasetError(f"unknown filter {text!r}; use one of: {', '.join(FILTER_FORMS)} (N: 0-100)")


def reviews_of(paths: Sequence[Path]) -> list[ReviewRecord | None]:
    """Each episode file's current review decision (None: never decided), read beside it."""
    reviews = []
    for path in paths:
        try:
            reviews.append(current_review(path))
        except (ValueError, OSError) as error:
            raise DatasetError(f"unreadable review decision: {error}") from error
    return reviews


def review_masks(
    names: Sequence[str], reviews: Sequence[ReviewRecord | None]
) -> dict[str, list[str]]:
    """The filter keys ``accepted`` and ``rejected``, each in the dataset's demo order."""
    decisions = [review.decision if review is not None else None for review in reviews]
    return {
        key: [name for name, decision in zip(names, decisions, strict=True) if decision == key]
        for key in ("accepted", "rejected")
    }


def review_attrs(review: ReviewRecord | None) -> dict[str, str]:
    """A demo's decision as attributes ("" where none): who decided, why."""
    if review is None or review.decision is None:
        return {"review_decision": "", "review_reason": "", "reviewer": ""}
    return {
        "review_decision": review.decision,
        "review_reason": review.reason,
        "reviewer": review.reviewer,
    }
