"""Review decisions as the dataset tools see them: a small JSON object stored next to its
episode file, one per decision, never overwritten.

The coordinator's database holds the history (who decided what, when); the copy beside the
episode lets `crowdteleop dataset build --filter accepted` work on the stored episodes alone,
on any machine, with no access to that database. Episode ``<dir>/<name>.hdf5`` has its
decisions at ``<dir>/<name>.review.<seq>.json`` (seq zero-padded, so names sort by it): the
highest seq is the current decision. Immutable objects keep the storage's put-once rule and
make two writers of one decision harmless.
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from crowdteleop.vocab import ReviewDecision

REVIEW_MARK = ".review."
SEQ_DIGITS = 6


class ReviewRecord(BaseModel):
    """One decision on one episode: accept, reject, or undo (``decision`` None)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    episode_id: str = Field(min_length=1, max_length=64)
    seq: int = Field(ge=1, description="the episode's decision count after this one")
    decision: ReviewDecision | None = Field(description="None: undone, undecided again")
    reason: str = Field("", max_length=2000)
    reviewer: str = Field(min_length=1, max_length=64, description='a name, or "auto"')
    automatic: bool = Field(False, description="decided by the campaign's score rule")
    at: float = Field(description="Unix seconds")


def review_name(episode_name: str, seq: int) -> str:
    """The file name of decision ``seq`` of the episode file named ``episode_name``."""
    stem = PurePosixPath(episode_name).stem
    return f"{stem}{REVIEW_MARK}{seq:0{SEQ_DIGITS}d}.json"


def is_review_name(name: str) -> bool:
    """Whether a stored object's name is a review decision's."""
    return REVIEW_MARK in name and name.endswith(".json")


def current_review(episode_path: Path) -> ReviewRecord | None:
    """The latest decision stored beside a local episode file, or None if it has none; a
    ValueError naming the file if it is not one."""
    pattern = f"{episode_path.stem}{REVIEW_MARK}{'[0-9]' * SEQ_DIGITS}.json"
    files = sorted(episode_path.parent.glob(pattern))
    if not files:
        return None
    try:
        return ReviewRecord.model_validate_json(files[-1].read_text(encoding="utf-8"))
    except ValidationError as error:
        reason = error.errors()[0]["msg"]
        raise ValueError(f"{files[-1]} is not a review decision ({reason})") from error
