"""The workers page's API (admin bearer token): each worker's record and reputation, their
episodes, blocking, and the bonus files of accepted demonstrations (docs/workers.md)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, Path, Query
from fastapi.responses import PlainTextResponse

from crowdteleop.coord.api.deps import WorkerRecordsDep, require_admin
from crowdteleop.coord.api.schemas import (
    BlockRequest,
    ErrorBody,
    WorkerDetailView,
    WorkerEpisodeView,
    WorkerStatsView,
    WorkerSummaryView,
)
from crowdteleop.coord.service.campaign import NAME_PATTERN
from crowdteleop.coord.service.reputation import WorkerRecord

ERRORS: dict[int | str, dict[str, Any]] = {code: {"model": ErrorBody} for code in (401, 404, 422)}
router = APIRouter(
    prefix="/api/admin", tags=["admin"], dependencies=[Depends(require_admin)], responses=ERRORS
)
WorkerId = Annotated[str, Path(pattern=r"^[A-Za-z0-9_-]{1,40}$", description="a worker id")]
SortKey = Literal[
    "reputation",
    "demonstrations",
    "success_rate",
    "median_score",
    "acceptance_rate",
    "median_time_s",
    "created_at",
]


def summary(record: WorkerRecord) -> WorkerSummaryView:
    worker = record.worker
    return WorkerSummaryView(
        worker_id=worker.id,
        source=worker.source,
        external_id=worker.external_id,
        campaign=worker.campaign,
        created_at=worker.created_at,
        blocked_at=worker.blocked_at,
        blocked_reason=worker.blocked_reason,
        reputation=record.reputation,
        stats=WorkerStatsView.model_validate(record.stats, from_attributes=True),
    )


def _sort_value(view: WorkerSummaryView, key: SortKey) -> float:
    """Missing figures sort last (descending) or first (ascending): as the lowest."""
    owner = view if key in ("reputation", "created_at") else view.stats
    value = getattr(owner, key)
    return float("-inf") if value is None else float(value)


@router.get("/workers", response_model=list[WorkerSummaryView])
async def workers(
    records: WorkerRecordsDep,
    campaign: Annotated[str | None, Query(pattern=NAME_PATTERN)] = None,
    sort: SortKey = "reputation",
    descending: bool = True,
) -> list[WorkerSummaryView]:
    """Every worker (with a session in `campaign`, if given) with their figures and
    reputation, sorted by `sort`."""
    views = [summary(record) for record in await records.records(campaign)]
    return sorted(views, key=lambda view: _sort_value(view, sort), reverse=descending)


@router.get("/workers/{worker_id}", response_model=WorkerDetailView)
async def worker(worker_id: WorkerId, records: WorkerRecordsDep) -> WorkerDetailView:
    """A worker's figures and reputation, and every episode with its score, flags and
    review decision."""
    record, episodes = await records.record(worker_id)
    return WorkerDetailView(
        **summary(record).model_dump(),
        episodes=[WorkerEpisodeView.model_validate(e, from_attributes=True) for e in episodes],
    )


@router.post("/workers/{worker_id}/block", response_model=WorkerDetailView)
async def block(
    worker_id: WorkerId, body: BlockRequest, records: WorkerRecordsDep
) -> WorkerDetailView:
    """Refuse the worker's joins and new sessions (403 `blocked`) and end their live one."""
    await records.block(worker_id, body.reason)
    return await worker(worker_id, records)


@router.post("/workers/{worker_id}/unblock", response_model=WorkerDetailView)
async def unblock(worker_id: WorkerId, records: WorkerRecordsDep) -> WorkerDetailView:
    await records.unblock(worker_id)
    return await worker(worker_id, records)


@router.get("/bonus", response_class=PlainTextResponse)
async def bonus(
    records: WorkerRecordsDep,
    campaign: Annotated[str, Query(pattern=NAME_PATTERN)],
    platform: Annotated[Literal["prolific", "mturk"], Query(alias="format")] = "prolific",
    per_accepted: Annotated[float, Query(gt=0, le=1000, description="per accepted demo")] = 0.1,
) -> PlainTextResponse:
    """A bonus file for the study platform: Prolific's bulk bonus lines or MTurk's CSV
    (docs/workers.md), from the campaign's accepted demonstrations."""
    text = await records.bonus(campaign, platform, per_accepted)
    filename = f"bonus-{campaign}-{platform}.{'txt' if platform == 'prolific' else 'csv'}"
    return PlainTextResponse(
        text,
        media_type="text/csv",
        headers={"Content-Disposition": f'attachment; filename="{filename}"'},
    )
