"""The messages between the coordinator and a teleop server, defined once for both sides.

Both processes import these models: the coordinator builds an `Assignment` and an `OfferRequest`
and reads an `OfferAnswer`; the teleop server validates the first two and sends `EpisodeReport`s.
The STUN and TURN servers (`IceServer`) travel in a server's config and assignment and on to
the pages and the Python client. Importing this module loads no simulator (pydantic and the
vocabularies only).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from crowdteleop.recording.metadata import RegionChoice
from crowdteleop.recording.quality import EpisodeMetrics
from crowdteleop.teleop.protocol import EpisodeFeedback, PeerRole
from crowdteleop.vocab import DeviceKind, Outcome

MAX_OFFER_BYTES = 64 * 1024
Token = Annotated[str, Field(min_length=8, max_length=256)]

# What an episode report may claim: far beyond any real episode (task limits are minutes, control
# at most 500 Hz), far below what a database integer or the statistics can hold.
MAX_EPISODE_STEPS = 10**7
MAX_EPISODE_NUMBER = 10**6
MAX_EPISODE_DURATION_S = 86_400.0
MAX_TELEMETRY_DEPTH = 8
StepCount = Annotated[int, Field(ge=0, le=MAX_EPISODE_STEPS)]
EpisodeNumber = Annotated[int, Field(ge=0, le=MAX_EPISODE_NUMBER)]
EpisodeDurationS = Annotated[float, Field(ge=0, le=MAX_EPISODE_DURATION_S, allow_inf_nan=False)]

IceTransportPolicy = Literal["all", "relay"]  # WebRTC's RTCIceTransportPolicy


class IceServer(BaseModel):
    """A STUN or TURN server as WebRTC's `RTCIceServer` describes it: URLs, and for TURN the
    username and credential. One model from the coordinator's settings through the teleop
    server's config to the pages (`SessionView.ice_servers`) and the Python client; a bare URL
    string is read as a server without credentials, so configs written before still load."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    urls: list[str] = Field(min_length=1, description="stun:, turn: or turns: URLs")
    username: str | None = Field(None, max_length=512)
    credential: str | None = Field(None, max_length=512)

    @model_validator(mode="before")
    @classmethod
    def _from_url(cls, data: Any) -> Any:
        if isinstance(data, str):
            return {"urls": [data]}
        if isinstance(data, dict) and isinstance(data.get("urls"), str):
            return {**data, "urls": [data["urls"]]}
        return data

    @model_validator(mode="after")
    def _known_schemes(self) -> IceServer:
        for url in self.urls:
            if not url.startswith(("stun:", "turn:", "turns:")):
                raise ValueError(
                    f"an ICE server URL starts with stun:, turn: or turns:, got {url!r}"
                )
        return self


class OfferRequest(BaseModel):
    """`POST /offer` on a teleop server: a WebRTC offer and the session's token."""

    model_config = ConfigDict(extra="forbid")

    sdp: str = Field(max_length=MAX_OFFER_BYTES)
    type: Literal["offer"] = "offer"
    token: str = Field(max_length=256)
    role: PeerRole = "worker"
    admin_token: str | None = Field(None, max_length=256)


# The m= sections an offer needs per role. Every client talks on the `control` and `events`
# data channels (one `m=application` section); the worker's page watches the robot, so its
# offer also has a video section (the browser's rtc.js always adds one for the worker). The
# phone (phone.js) offers data channels only, and so may an admin bot driving without video.
REQUIRED_OFFER_SECTIONS: dict[PeerRole, tuple[str, ...]] = {
    "worker": ("application", "video"),
    "phone": ("application",),
    "admin": ("application",),
}


def missing_offer_sections(sdp: str, role: PeerRole) -> list[str]:
    """The media sections (``m=`` kinds) `role`'s offer needs but lacks; empty if none.

    Checked before a peer is made: aiortc answers even a bare ``v=0`` with an empty answer,
    and such a peer never connects, yet holds one of the session's few slots. An offer that
    cannot carry the session's channels (or, for the worker, its video) is refused outright.
    """
    offered = {line[2:].split(" ", 1)[0] for line in sdp.splitlines() if line.startswith("m=")}
    return [kind for kind in REQUIRED_OFFER_SECTIONS[role] if kind not in offered]


class OfferAnswer(BaseModel):
    """The teleop server's answer to an accepted offer."""

    sdp: str
    type: str
    peer_id: str


class Assignment(BaseModel):
    """`POST /assign`: a warm spare becomes a session's server (`crowdteleop.teleop.assign`).

    Authorized by the spare's current admin token; after it, only the new tokens work."""

    model_config = ConfigDict(extra="forbid")

    session_id: str = Field(min_length=1, max_length=128)
    worker_id: str = Field(min_length=1, max_length=128)
    token: Token
    admin_token: Token
    recording_directory: Path
    report_url: str | None = None
    report_token: str | None = Field(None, min_length=8, max_length=256)
    ice_servers: list[IceServer] = Field(
        default_factory=list, description="the session's (fresh TURN credentials among them)"
    )
    practice_s: float = Field(
        0.0, ge=0, le=600, description="the campaign's practice round for this worker; 0: none"
    )
    region: RegionChoice | None = None


class EpisodeReport(BaseModel):
    """What a teleop server POSTs to the coordinator for every stored episode."""

    model_config = ConfigDict(extra="ignore")  # newer teleop servers may say more

    session_id: str = Field(max_length=64)
    worker_id: str = Field(max_length=64)
    episode: EpisodeNumber
    episode_id: str = Field(min_length=1, max_length=64)
    outcome: Outcome
    steps: StepCount
    duration_s: EpisodeDurationS
    uri: str = Field(max_length=4096)
    telemetry: dict[str, Any] = Field(
        default_factory=dict,
        description=f"JSON with finite numbers, nested at most {MAX_TELEMETRY_DEPTH} deep",
    )
    device: DeviceKind | None = Field(
        None, description="the device that drove the episode, when the server knows it"
    )
    metrics: EpisodeMetrics | None = Field(
        None, description="its quality metrics, measured as it was stored (none: unmeasured)"
    )

    @field_validator("telemetry")
    @classmethod
    def _storable(cls, telemetry: dict[str, Any]) -> dict[str, Any]:
        """Python's JSON parser takes NaN and Infinity; a database's JSON column does not."""
        _check_json(telemetry, MAX_TELEMETRY_DEPTH)
        return telemetry


def _check_json(value: Any, depth: int) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError("numbers must be finite (no NaN or Infinity)")
    if isinstance(value, dict | list):
        if depth <= 0:
            raise ValueError(f"nested more than {MAX_TELEMETRY_DEPTH} deep")
        for item in value.values() if isinstance(value, dict) else value:
            _check_json(item, depth - 1)


class EpisodeAck(BaseModel):
    """The coordinator's answer to an `EpisodeReport`: counted (or a retry), the session's
    count, and the worker's feedback when the episode was measured."""

    model_config = ConfigDict(extra="ignore")  # newer coordinators may say more

    episode_id: str
    duplicate: bool
    demos_done: int
    demos_required: int
    completed: bool
    feedback: EpisodeFeedback | None = None


class TeleopHealth(BaseModel):
    """A teleop server's ``GET /health``: the coordinator's liveness probe reads it (and sums
    ``spool_pending`` and ``reports_pending`` into ``/metrics``)."""

    model_config = ConfigDict(frozen=True)

    status: Literal["ok"] = "ok"
    session_id: str
    peers: int
    state: str
    episodes: int
    successes: int
    ticks: int
    spool_pending: int = Field(
        0, ge=0, description="episodes in the local spool waiting for the object store"
    )
    reports_pending: int = Field(
        0, ge=0, description="stored episodes the coordinator has not yet confirmed hearing of"
    )
    reports_unreachable: bool = Field(
        False, description="the last report (or the start's probe) found no coordinator"
    )
