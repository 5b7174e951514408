"""The reviewer API's request and response bodies (coord/api/review.py, docs/review.md); the
answers the reviewer page acts on are among the views served at /views.json (schemas.py)."""

from __future__ import annotations

from typing import Self

from pydantic import BaseModel, ConfigDict, Field, model_validator

from crowdteleop.recording.quality import QualityFlag
from crowdteleop.vocab import Outcome, ReviewDecision


class ReviewerView(BaseModel):
    reviewer: str = Field(description='the name decisions are recorded under ("admin")')


class ReviewDecisionView(BaseModel):
    """One decision in an episode's history."""

    seq: int = Field(description="the episode's decision count after it")
    decision: ReviewDecision | None = Field(description="None: undecided again (an undo)")
    reason: str
    reviewer: str
    automatic: bool
    at: float = Field(description="Unix seconds")


class ReviewEpisodeView(BaseModel):
    """A card of the grid."""

    episode_id: str
    session_id: str
    worker_id: str
    task: str
    outcome: Outcome
    duration_s: float
    created_at: float
    score: float | None
    flags: list[QualityFlag] | None
    decision: ReviewDecision | None
    review_seq: int = Field(description="decisions so far: what a decision is made against")
    video_url: str = Field(description="the rendered video (signed, valid for an hour)")
    thumbnail_url: str = Field(description="its first frame as a JPEG (signed)")


class ReviewEpisodeDetail(ReviewEpisodeView):
    history: list[ReviewDecisionView] = Field(description="first first")


class ReviewPageView(BaseModel):
    episodes: list[ReviewEpisodeView]
    total: int = Field(description="episodes passing the filters")
    limit: int
    offset: int


class DecisionRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")

    decision: ReviewDecision
    reason: str = Field("", max_length=2000, description="why; required to reject")
    expected_seq: int = Field(ge=0, description="the review_seq the reviewer saw")

    @model_validator(mode="after")
    def _reject_says_why(self) -> Self:
        if self.decision == "rejected" and not self.reason.strip():
            raise ValueError("a rejection needs a reason")
        return self


class UndoRequest(BaseModel):
    model_config = ConfigDict(extra="forbid")

    expected_seq: int = Field(ge=1, description="the review_seq the reviewer saw")


class DecidedView(BaseModel):
    episode: ReviewEpisodeDetail
    decision: ReviewDecisionView = Field(description="the decision just recorded")


class ConflictBody(BaseModel):
    """409: decided by someone else meanwhile; the episode as it stands now (the error body
    of every endpoint, `schemas.ErrorBody`, with the episode)."""

    error: str = Field(description="conflict")
    message: str
    episode: ReviewEpisodeDetail
