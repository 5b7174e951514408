"""Pydantic models of every request and response body of the HTTP API."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from crowdteleop.coord.api.review_schemas import DecidedView, ReviewEpisodeDetail, ReviewPageView
from crowdteleop.recording.metadata import RegionName, RoundTripMs
from crowdteleop.recording.quality import EpisodeMetrics, QualityFlag
from crowdteleop.teleop.messages import IceServer, IceTransportPolicy
from crowdteleop.vocab import Outcome, WorkerDevice

SessionState = Literal["queued", "starting", "ready", "ended"]
EndedReason = Literal["left", "timeout", "abandoned", "completed", "error", "queue_timeout"]
MAX_SDP = 64 * 1024
ID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ErrorBody(BaseModel):
    error: str = Field(description="machine-readable code, e.g. not_found")
    message: str


class JoinRequest(Strict):
    params: dict[str, str] = Field(
        default_factory=dict, description="the join link's query-string parameters"
    )
    campaign: str | None = Field(None, max_length=64)
    worker_token: str | None = Field(
        None,
        max_length=512,
        description="the token this browser was given before: proves a rejoin is the same browser",
    )
    take_over: bool = Field(
        False,
        description="move the worker's live session here from another browser (it is told)",
    )
    region_rtts_ms: dict[RegionName, RoundTripMs] | None = Field(
        None,
        max_length=16,
        description="the round trips the join page measured to the campaign's regions (the "
        "nearest with a free robot sent the worker here): recorded with their episodes",
    )

    @field_validator("params")
    @classmethod
    def _bounded(cls, params: dict[str, str]) -> dict[str, str]:
        if len(params) > 32:
            raise ValueError("at most 32 parameters")
        for key, value in params.items():
            if len(key) > 64 or len(value) > 256:
                raise ValueError("parameter names are at most 64 characters, values 256")
        return params


class RegionView(BaseModel):
    name: str
    url: str = Field(description="its coordinator's public URL: its /api/ping, its join page")


class PingView(BaseModel):
    """How free a region is, from `GET /api/ping` (its round trip is the other half)."""

    region: str | None = Field(description="this coordinator's region; null without regions")
    capacity: int = Field(description="robots this region runs at once")
    free_slots: int = Field(description="robots free now")
    queued: int = Field(description="workers waiting for one")


class RobotPreparation(BaseModel):
    """A robot (teleop server) on its way, for the pages' countdown and progress bar."""

    eta_s: float = Field(ge=0, description="about how many seconds until it is ready")
    total_s: float = Field(
        ge=0, description="how long a start takes here (the median of recent ones it measured)"
    )


class CampaignView(BaseModel):
    name: str
    title: str
    instructions: str
    tasks: list[str]
    interfaces: list[WorkerDevice]
    demos_required: int
    time_limit_s: float
    typical_session_s: float | None = Field(
        None, description="how long sessions have taken (mean of recent ones); null before any"
    )
    regions: list[RegionView] = Field(
        default_factory=list, description="where the campaign is served; empty: here alone"
    )
    region: str | None = Field(None, description="the region this coordinator is")
    robot: RobotPreparation | None = Field(
        None,
        description="how long a worker joining now would wait for a robot with a slot free "
        "(eta 0: a warm one is ready); null when every slot is held (the queue's wait is told "
        "once in line)",
    )


class JoinResponse(BaseModel):
    worker_id: str
    worker_token: str
    source: Literal["prolific", "mturk", "anonymous"]
    campaign: CampaignView


class SessionView(BaseModel):
    session_id: str
    state: SessionState
    queue_position: int | None = Field(description="1-based; null unless queued")
    eta_s: float | None = Field(description="estimated wait; null unless queued")
    task: str
    robot: str
    controller: str
    instruction: str
    interfaces: list[WorkerDevice]
    time_limit_s: float
    time_left_s: float | None = Field(description="while ready: seconds before the time limit")
    demos_done: int
    demos_required: int
    completion_code: str | None
    redirect_url: str | None
    ice_servers: list[IceServer] = Field(description="with this session's TURN credentials")
    ice_transport_policy: IceTransportPolicy = "all"
    ended_reason: EndedReason | None
    notice: str | None = Field(
        None, description="why a running session waits again (its robot crashed or hung)"
    )
    ready_at: float | None = Field(
        None, description="when the session's current robot became ready: a new value, a new robot"
    )
    preparing: RobotPreparation | None = Field(
        None, description="while starting: how long until its robot is ready; null otherwise"
    )
    accepted_required: int | None = Field(
        None,
        description="accepted demonstrations the completion code waits for; null: the "
        "campaign does not hold it for review (docs/workers.md)",
    )
    accepted: int | None = Field(None, description="of them accepted so far (null: no hold)")
    awaiting_review: int | None = Field(
        None, description="successful demonstrations not yet decided (null: no hold)"
    )


class HeartbeatRequest(Strict):
    interface: WorkerDevice | None = Field(None, description="the device the worker is using now")


class OfferBody(Strict):
    sdp: str = Field(max_length=MAX_SDP)
    type: Literal["offer"]


class PairingView(BaseModel):
    code: str
    expires_s: float
    phone_url: str


class PairRequest(Strict):
    code: str = Field(max_length=32)
    key: str | None = Field(
        None,
        max_length=128,
        description="the long key of the QR code's link: never rate limited (unguessable)",
    )


class PairResponse(BaseModel):
    phone_token: str
    session_id: str


class PhoneSessionView(BaseModel):
    session_id: str
    state: SessionState
    task: str
    instruction: str
    ended_reason: EndedReason | None
    ice_servers: list[IceServer]
    ice_transport_policy: IceTransportPolicy = "all"


class EpisodeView(BaseModel):
    episode_id: str
    session_id: str
    worker_id: str
    number: int
    outcome: Outcome
    steps: int
    duration_s: float
    uri: str
    interface: str | None
    task: str
    created_at: float
    metrics: EpisodeMetrics | None = Field(
        None, description="its quality metrics (none: reported unmeasured)"
    )
    score: float | None = Field(
        None,
        description="0-100 against its campaign's successful episodes of the task, when "
        "it was reported (none: unmeasured)",
    )
    flags: list[QualityFlag] | None = Field(None, description="why it stands out, if it does")


class TeleopAccess(BaseModel):
    url: str
    token: str
    admin_token: str


class SessionSummary(BaseModel):
    session_id: str
    worker_id: str
    campaign: str
    state: SessionState
    queue_position: int | None
    task: str
    robot: str
    controller: str
    interface: str | None
    demos_done: int
    demos_required: int
    created_at: float
    ready_at: float | None
    last_heartbeat_s_ago: float
    teleop_url: str | None
    rtt_ms: float | None = Field(
        None, description="the worker's round trip to this region, as their join page measured"
    )


class TeleopServerView(BaseModel):
    session_id: str
    url: str | None
    pid: int | None
    alive: bool
    started_at: float


class HourCount(BaseModel):
    hour_start: float = Field(description="Unix seconds")
    episodes: int
    successes: int


class DurationSummary(BaseModel):
    key: str
    successes: int
    episodes: int
    mean_s: float | None
    median_s: float | None
    min_s: float | None
    max_s: float | None


class AdminOverview(BaseModel):
    now: float
    capacity: int
    sessions: list[SessionSummary]
    queue: list[SessionSummary]
    teleop_servers: list[TeleopServerView]
    demos_per_hour: list[HourCount]
    completion_time_per_worker: list[DurationSummary]
    completion_time_per_interface: list[DurationSummary]
    totals: dict[str, int]
    refusals: dict[str, int] = Field(description="requests refused by each limit, since start")
    restarts: int = Field(description="sessions given a new teleop server, since start")


class ChartBin(BaseModel):
    """One bin of the admin page's time charts (bin_s long; the last one still filling)."""

    start_s: float = Field(description="the bin's start, Unix seconds")
    episodes: int = Field(description="episodes reported in the bin")
    successes: int = Field(description="of them successful: demonstrations")
    queue_length_mean: float = Field(description="workers waiting, averaged over the bin's time")
    queue_length_max: int = Field(description="the most waiting at once")
    queue_wait_s_median: float | None = Field(
        description="median wait of those who left the queue in the bin (admitted or gone)"
    )
    queue_wait_s_max: float | None = Field(description="the longest of those waits")
    live_sessions_mean: float = Field(description="sessions holding a robot, averaged over time")
    live_sessions_max: int = Field(description="the most at once")
    latency_p50_ms: float | None = Field(
        description="median over the bin's episodes of each one's median control-to-photon "
        "latency (null: none measured)"
    )
    latency_p95_ms: float | None = Field(
        description="median over the bin's episodes of each one's 95th percentile"
    )


class ScoreBin(BaseModel):
    score_from: float = Field(description="0-100, inclusive")
    score_to: float = Field(description="exclusive, but for the last bin's 100")
    demonstrations: int


class AdminCharts(BaseModel):
    """The admin page's charts over the last hours, derived from the database's sessions and
    episodes (so the same after a restart and on every replica)."""

    now_s: float = Field(description="Unix seconds when it was computed")
    bin_s: float = Field(description="each bin's length")
    bins: list[ChartBin] = Field(description="oldest first, clock-aligned")
    scores: list[ScoreBin] = Field(
        description="quality scores of the window's successful episodes, in bins of 10"
    )
    unscored: int = Field(description="successful episodes of the window without a score")


class WorkerStatsView(BaseModel):
    """A worker's figures (docs/workers.md); rates are 0-1, null without any to count."""

    episodes: int
    demonstrations: int = Field(description="successful episodes")
    success_rate: float | None
    median_score: float | None = Field(description="of the scored demonstrations, 0-100")
    accepted: int
    rejected: int
    undecided: int = Field(description="demonstrations without a review decision")
    acceptance_rate: float | None = Field(description="accepted over decided")
    flags: dict[str, int] = Field(description="flags raised, by metric")
    median_time_s: float | None = Field(description="per demonstration")


class WorkerSummaryView(BaseModel):
    worker_id: str
    source: Literal["prolific", "mturk", "anonymous"]
    external_id: str | None = Field(description="their study platform's id (PROLIFIC_PID, ...)")
    campaign: str = Field(description="the campaign of the link they came by last")
    created_at: float
    blocked_at: float | None
    blocked_reason: str | None
    reputation: float = Field(description="0-100 (docs/workers.md)")
    stats: WorkerStatsView


class WorkerEpisodeView(BaseModel):
    episode_id: str
    session_id: str
    number: int
    outcome: Outcome
    duration_s: float
    task: str
    created_at: float
    score: float | None
    flags: list[QualityFlag] | None
    decision: Literal["accepted", "rejected"] | None


class WorkerDetailView(WorkerSummaryView):
    episodes: list[WorkerEpisodeView] = Field(description="oldest first")


class BlockRequest(Strict):
    reason: str = Field(
        "", max_length=500, description="kept for the admins, never shown to the worker"
    )


# The answers the pages check before acting on them, by name (served at /views.json).
PAGE_VIEWS: dict[str, type[BaseModel]] = {
    "SessionView": SessionView,
    "CampaignView": CampaignView,
    "ReviewPageView": ReviewPageView,
    "ReviewEpisodeDetail": ReviewEpisodeDetail,
    "DecidedView": DecidedView,
}


def page_views_schema() -> dict[str, Any]:
    """The JSON Schema of each of PAGE_VIEWS, as the API serializes it."""
    return {
        name: model.model_json_schema(mode="serialization") for name, model in PAGE_VIEWS.items()
    }
