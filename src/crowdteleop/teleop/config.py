"""Typed configuration of one teleop server process (one session, one worker)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from crowdteleop.control.config import ControlConfig
from crowdteleop.recording.metadata import RegionChoice
from crowdteleop.recording.storage import EpisodeStorage
from crowdteleop.recording.stores import StorageConfig, open_storage
from crowdteleop.sim.config import SimConfig
from crowdteleop.tasks import get_task
from crowdteleop.teleop.messages import IceServer
from crowdteleop.vocab import CONTROLLERS, action_mode_for

Codec = Literal["vp8", "h264"]

# aiortc's own clamps (aiortc.codecs.vpx / .h264); our values must lie inside them.
CODEC_LIMITS_BPS = {"vp8": (250_000, 1_500_000), "h264": (500_000, 3_000_000)}
# (floor, start, ceiling) per codec when the config leaves them out. VP8 starts below a
# 500 kbps link; H.264 cannot go below 500 kbps in aiortc, so it starts at its floor.
DEFAULT_BITRATES_BPS = {
    "vp8": (250_000, 300_000, 1_500_000),
    "h264": (500_000, 500_000, 3_000_000),
}


class VideoConfig(BaseModel):
    """The stream the worker watches.

    VP8 starts at 300 kbps (not aiortc's 500 kbps) so a 500 kbps link never builds a standing
    queue before the receiver's estimate arrives; 320x240 at 20 fps looks clean at that rate.
    Bitrates left out take the codec's defaults (`DEFAULT_BITRATES_BPS`).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    camera: str = "frontview"
    width: int = Field(320, ge=16, le=1920, multiple_of=2)
    height: int = Field(240, ge=16, le=1080, multiple_of=2)
    codec: Codec = "vp8"
    start_bitrate_bps: int = 0
    min_bitrate_bps: int = 0
    max_bitrate_bps: int = 0
    keepalive_fps: float = Field(
        2.0, gt=0, le=30, description="frames per second sent while nothing in view moves"
    )

    @property
    def mime_type(self) -> str:
        """The codec's RTP name, as WebRTC capabilities and aiortc's encoders know it."""
        return "video/VP8" if self.codec == "vp8" else "video/H264"

    @model_validator(mode="before")
    @classmethod
    def _codec_defaults(cls, data: object) -> object:
        if isinstance(data, dict):
            floor, start, ceiling = DEFAULT_BITRATES_BPS[data.get("codec", "vp8")]
            data = {
                "min_bitrate_bps": floor,
                "start_bitrate_bps": start,
                "max_bitrate_bps": ceiling,
                **data,
            }
        return data

    @model_validator(mode="after")
    def _bitrates_fit_the_codec(self) -> VideoConfig:
        low, high = CODEC_LIMITS_BPS[self.codec]
        values = (self.min_bitrate_bps, self.start_bitrate_bps, self.max_bitrate_bps)
        if not low <= self.min_bitrate_bps <= self.start_bitrate_bps <= self.max_bitrate_bps:
            raise ValueError(
                f"bitrates must satisfy {low} <= min <= start <= max for {self.codec}, got {values}"
            )
        if self.max_bitrate_bps > high:
            raise ValueError(f"{self.codec} max bitrate is {high} bps in aiortc")
        return self


class LimitsConfig(BaseModel):
    """What one peer may send before its messages are refused, how many peers a session
    takes, and how long a peer may hold its slot without a connection."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    max_message_bytes: int = Field(4096, ge=256, le=1 << 20)
    messages_per_second: float = Field(200.0, gt=0, description="sustained, per peer")
    burst: int = Field(100, ge=1, description="messages a peer may send at once")
    max_peers: int = Field(4, ge=1, le=16)
    max_input_age_ms: float = Field(
        500.0,
        gt=0,
        description="a pose, press or gripper command older than this on arrival (the "
        "client's clock mapped onto ours through ping / pong) is not applied; releases always are",
    )
    video_stall_ms: float = Field(
        1000.0,
        gt=0,
        description="the worker's page reports its video stalled after this long without a new "
        "frame, and the clutch is released until the device lets go and presses again",
    )
    connect_timeout_s: float = Field(
        15.0,
        gt=0,
        description="a peer not connected this long after its offer (or after losing its "
        "connection) is dropped, so an offer whose ICE never completes frees its slot",
    )


class RecordingConfig(BaseModel):
    """Where episodes are recorded and stored; ``storage`` picks a local directory (default)
    or S3 behind a local spool (``crowdteleop.recording.stores``, docs/dataset.md)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    directory: Path = Path("data/episodes")
    keep_failed: bool = Field(True, description="keep reset / timeout / disconnect episodes")
    labels: dict[str, str] = Field(
        default_factory=dict,
        max_length=16,
        description="metadata every episode of this server carries, e.g. network_condition "
        "(the dataset's `network` grouping and filter keys read it)",
    )
    flush_interval_s: float = Field(1.0, gt=0, le=1.0)
    storage: StorageConfig = StorageConfig()

    def open_storage(self) -> EpisodeStorage:
        """The store episodes go to (an S3 store starts its spool's upload thread)."""
        return open_storage(self.storage, self.directory)


class TeleopConfig(BaseModel):
    """Everything one teleop server needs; the coordination server fills it per worker."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    session_id: str = "local"
    worker_id: str = "anonymous"
    token: str = Field("dev-token", min_length=8, description="workers' bearer token")
    admin_token: str | None = Field(None, min_length=8, description="enables the admin channel")
    sim: SimConfig = SimConfig()
    control: ControlConfig = ControlConfig()
    video: VideoConfig = VideoConfig()
    limits: LimitsConfig = LimitsConfig()
    recording: RecordingConfig = RecordingConfig()
    ice_servers: list[IceServer] = Field(
        default_factory=list,
        description="STUN/TURN servers (a bare URL, or urls/username/credential); none on loopback",
    )
    report_url: str | None = Field(
        None, description="the coordination server's URL for episode reports (POST JSON)"
    )
    report_token: str | None = Field(None, min_length=8, description="bearer token for reports")
    allowed_origins: list[str] = Field(
        default_factory=list,
        description="browser origins (besides our own) whose requests we take: the "
        "coordinator's; a request with any other Origin header is refused (teleop/origin.py)",
    )
    standby: bool = Field(
        False, description="a warm spare: refuses offers until POST /assign gives it a session"
    )
    time_limit_s: float | None = Field(None, gt=0, description="default: the task's limit")
    success_hold_steps: int = Field(10, ge=1, description="as robosuite's demo collector")
    practice_s: float = Field(
        0.0,
        ge=0,
        le=600,
        description="a practice round (reach a green ball, nothing recorded) of this many "
        "seconds before the worker's first episode; 0: none. The coordinator sets its "
        "campaign's (20 s by default); off here so scripts and benchmarks record at once",
    )
    region: RegionChoice | None = Field(
        None, description="the worker's region and measured round trips, for the episodes"
    )
    telemetry_interval_s: float = Field(1.0, gt=0)
    seed: int = 0

    @model_validator(mode="before")
    @classmethod
    def _action_mode_follows_controller(cls, data: object) -> object:
        """The simulation's action mode is the controller's, filled in here: a config names the
        controller once (an explicit, different ``sim.action_mode`` is refused below)."""
        if not isinstance(data, dict):
            return data
        control = data.get("control") or {}
        controller = (
            control.controller
            if isinstance(control, ControlConfig)
            else control.get("controller", "ik-velocity")
        )
        sim = data.get("sim") or {}
        if isinstance(sim, dict) and "action_mode" not in sim and controller in CONTROLLERS:
            data = {**data, "sim": {**sim, "action_mode": action_mode_for(controller)}}
        return data

    @model_validator(mode="after")
    def _controller_matches_sim(self) -> TeleopConfig:
        if self.control.action_mode != self.sim.action_mode:
            raise ValueError(
                f"controller {self.control.controller!r} drives action mode "
                f"{self.control.action_mode!r}, not sim.action_mode {self.sim.action_mode!r}"
            )
        if self.admin_token is not None and self.admin_token == self.token:
            raise ValueError("admin_token must differ from the workers' token")
        return self

    @property
    def episode_time_limit_s(self) -> float:
        return self.time_limit_s or get_task(self.sim.task).time_limit_s
