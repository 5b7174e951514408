"""The reviewer's API (docs/review.md): the episodes grid with filters and sorts, an episode with
its decision history, accept / reject / undo against the decision count the reviewer saw, and
each episode's rendered video and thumbnail behind signed links.

Who may review: the admin token (recorded as "admin") or a reviewer's token from
`CoordConfig.reviewer_tokens` (recorded under their name). Wrong tokens count and are limited
as wrong admin tokens are.
"""

from __future__ import annotations

from typing import Annotated, Any, TypeVar

from fastapi import APIRouter, Depends, Path, Query, Request
from fastapi.responses import FileResponse, JSONResponse
from pydantic import BaseModel, ValidationError

from crowdteleop.coord.api.deps import ClientDep, ConfigDep, Credentials, GuardsDep, token_of
from crowdteleop.coord.api.review_schemas import (
    ConflictBody,
    DecidedView,
    DecisionRequest,
    ReviewDecisionView,
    ReviewEpisodeDetail,
    ReviewEpisodeView,
    ReviewerView,
    ReviewPageView,
    UndoRequest,
)
from crowdteleop.coord.api.schemas import ErrorBody
from crowdteleop.coord.db.tables import Episode, ReviewDecisionRow
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.guard.security import same
from crowdteleop.coord.service.metrics import CoordMetrics
from crowdteleop.coord.service.review import Decided, DecidedMeanwhileError, Reviews
from crowdteleop.coord.service.review import ReviewFilters as ReviewFilters
from crowdteleop.coord.service.review_video import EpisodeVideos, MediaLinks, RenderError

ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorBody} for code in (401, 404, 409, 422, 429)
}
router = APIRouter(prefix="/api/review", tags=["review"], responses=ERRORS)
EpisodeId = Annotated[str, Path(pattern=r"^[A-Za-z0-9_.:-]{1,64}$", description="an episode")]


def get_reviews(request: Request) -> Reviews:
    reviews: Reviews = request.app.state.reviews
    return reviews


def get_videos(request: Request) -> EpisodeVideos:
    videos: EpisodeVideos = request.app.state.review_videos
    return videos


def get_links(request: Request) -> MediaLinks:
    links: MediaLinks = request.app.state.review_links
    return links


def get_metrics(request: Request) -> CoordMetrics:
    metrics: CoordMetrics = request.app.state.metrics
    return metrics


ReviewsDep = Annotated[Reviews, Depends(get_reviews)]
VideosDep = Annotated[EpisodeVideos, Depends(get_videos)]
LinksDep = Annotated[MediaLinks, Depends(get_links)]
MetricsDep = Annotated[CoordMetrics, Depends(get_metrics)]


async def current_reviewer(
    config: ConfigDep, credentials: Credentials, guards: GuardsDep, client: ClientDep
) -> str:
    """The reviewer's name: "admin" for the admin token, else their configured name."""
    guards.check_admin(client)
    token = token_of(credentials)
    if token is not None:
        if same(token, config.admin_token):
            return "admin"
        for name, expected in config.reviewer_tokens.items():
            if same(token, expected):
                return name
    guards.admin_failed(client)
    raise ApiError(401, "unauthorized", "a reviewer's token (or the admin token) is required")


Reviewer = Annotated[str, Depends(current_reviewer)]


M = TypeVar("M", bound=BaseModel)


def parsed(model: type[M], data: Any, metrics: CoordMetrics) -> M:
    """`data` as `model`; a 422 naming each bad field (counted) otherwise."""
    try:
        return model.model_validate(data)
    except ValidationError as error:
        metrics.refused("review_invalid")
        problems = [
            f"{'.'.join(str(p) for p in e['loc']) or 'body'}: {e['msg']}"
            for e in error.errors()[:5]
        ]
        raise ApiError(422, "invalid_request", "; ".join(problems)) from None


async def json_body(request: Request, metrics: CoordMetrics) -> Any:
    try:
        return await request.json()
    except ValueError:
        metrics.refused("review_invalid")
        raise ApiError(422, "invalid_request", "the body is not JSON") from None


def card(episode: Episode, links: MediaLinks) -> ReviewEpisodeView:
    base = f"/api/review/episodes/{episode.episode_id}"
    query = links.query(episode.episode_id)
    return ReviewEpisodeView.model_validate(
        {
            **{name: getattr(episode, name) for name in CARD_FIELDS},
            "video_url": f"{base}/video?{query}",
            "thumbnail_url": f"{base}/thumbnail?{query}",
        }
    )


CARD_FIELDS = [
    name for name in ReviewEpisodeView.model_fields if name not in ("video_url", "thumbnail_url")
]


def detail(
    episode: Episode, history: list[ReviewDecisionRow], links: MediaLinks
) -> ReviewEpisodeDetail:
    return ReviewEpisodeDetail(
        **card(episode, links).model_dump(),
        history=[ReviewDecisionView.model_validate(r, from_attributes=True) for r in history],
    )


@router.get("/me", response_model=ReviewerView)
async def me(reviewer: Reviewer) -> ReviewerView:
    """Who this token reviews as (the page checks a token with it)."""
    return ReviewerView(reviewer=reviewer)


@router.get("/episodes", response_model=ReviewPageView, dependencies=[Depends(current_reviewer)])
async def episodes(
    request: Request, reviews: ReviewsDep, links: LinksDep, metrics: MetricsDep
) -> ReviewPageView:
    """A page of the episodes passing the filters (query: task, worker, decision
    accepted|rejected|undecided, flagged, score_min, score_max, outcome, sort
    score|created_at|duration_s, descending, limit, offset); a malformed one is a 422."""
    filters = parsed(ReviewFilters, dict(request.query_params), metrics)
    page = await reviews.page(filters)
    return ReviewPageView(
        episodes=[card(episode, links) for episode in page.episodes],
        total=page.total,
        limit=filters.limit,
        offset=filters.offset,
    )


@router.get(
    "/episodes/{episode_id}",
    response_model=ReviewEpisodeDetail,
    dependencies=[Depends(current_reviewer)],
)
async def episode(episode_id: EpisodeId, reviews: ReviewsDep, links: LinksDep) -> Any:
    return detail(*await reviews.episode(episode_id), links)


async def _decided(
    reviews: Reviews, links: MediaLinks, episode_id: str, decide: Any
) -> DecidedView | JSONResponse:
    """A decision's answer; a 409 with the episode as it stands when someone was quicker."""
    try:
        decided: Decided = await decide
    except DecidedMeanwhileError as conflict:
        now = detail(*await reviews.episode(episode_id), links)
        body = ConflictBody(error=conflict.code, message=conflict.message, episode=now)
        return JSONResponse(body.model_dump(mode="json"), status_code=409)
    _, history = await reviews.episode(episode_id)
    return DecidedView(
        episode=detail(decided.episode, history, links),
        decision=ReviewDecisionView.model_validate(decided.decision, from_attributes=True),
    )


@router.post(
    "/episodes/{episode_id}/decision",
    response_model=DecidedView,
    responses={409: {"model": ConflictBody}},
)
async def decision(
    episode_id: EpisodeId,
    request: Request,
    reviewer: Reviewer,
    reviews: ReviewsDep,
    links: LinksDep,
    metrics: MetricsDep,
) -> Any:
    """Accept or reject (with a reason) against `expected_seq`, the count the reviewer saw."""
    body = parsed(DecisionRequest, await json_body(request, metrics), metrics)
    decide = reviews.decide(
        episode_id, body.expected_seq, body.decision, body.reason.strip(), reviewer
    )
    return await _decided(reviews, links, episode_id, decide)


@router.post(
    "/episodes/{episode_id}/undo",
    response_model=DecidedView,
    responses={409: {"model": ConflictBody}},
)
async def undo(
    episode_id: EpisodeId,
    request: Request,
    reviewer: Reviewer,
    reviews: ReviewsDep,
    links: LinksDep,
    metrics: MetricsDep,
) -> Any:
    """Undo the last decision: a new decision back to the one before it, kept in the history."""
    body = parsed(UndoRequest, await json_body(request, metrics), metrics)
    return await _decided(
        reviews, links, episode_id, reviews.undo(episode_id, body.expected_seq, reviewer)
    )


async def _signed_episode(
    episode_id: str, expires: int, sig: str, reviews: Reviews, links: MediaLinks
) -> Episode:
    if not links.valid(episode_id, expires, sig):
        raise ApiError(401, "unauthorized", "this link is wrong or expired: reload the page")
    episode, _ = await reviews.episode(episode_id)
    return episode


Expires = Annotated[int, Query(ge=0)]
Signature = Annotated[str, Query(pattern=r"^[0-9a-f]{32}$")]


@router.get("/episodes/{episode_id}/video", response_class=FileResponse)
async def video(
    episode_id: EpisodeId,
    expires: Expires,
    sig: Signature,
    reviews: ReviewsDep,
    links: LinksDep,
    videos: VideosDep,
) -> FileResponse:
    """The episode rendered from its recorded states (MP4; ranges, so the player seeks)."""
    episode = await _signed_episode(episode_id, expires, sig, reviews, links)
    try:
        path = await videos.video(episode)
    except RenderError as error:
        raise ApiError(502, "render_failed", f"cannot render {episode_id}: {error}") from None
    return FileResponse(path, media_type="video/mp4", headers={"Cache-Control": "private"})


@router.get("/episodes/{episode_id}/thumbnail", response_class=FileResponse)
async def thumbnail(
    episode_id: EpisodeId,
    expires: Expires,
    sig: Signature,
    reviews: ReviewsDep,
    links: LinksDep,
    videos: VideosDep,
) -> FileResponse:
    """The first frame of the episode's video (JPEG)."""
    episode = await _signed_episode(episode_id, expires, sig, reviews, links)
    try:
        path = await videos.thumbnail(episode)
    except RenderError as error:
        raise ApiError(502, "render_failed", f"cannot render {episode_id}: {error}") from None
    return FileResponse(path, media_type="image/jpeg", headers={"Cache-Control": "private"})
