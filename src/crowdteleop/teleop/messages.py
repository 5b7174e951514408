"""The messages between the coordinator and a teleop server, defined once for both sides.

Both processes import these models: the coordinator builds an `Assignment` and an `OfferRequest`
and reads an `OfferAnswer`; the teleop server validates the first two and sends `EpisodeReport`s.
Importing this module loads no simulator (pydantic and the vocabularies only).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from crowdteleop.teleop.protocol import PeerRole
from crowdteleop.vocab import DeviceKind, Outcome

MAX_OFFER_BYTES = 64 * 1024
Token = Annotated[str, Field(min_length=8, max_length=256)]


class OfferRequest(BaseModel):
    """`POST /offer` on a teleop server: a WebRTC offer and the session's token."""

    model_config = ConfigDict(extra="forbid")

    sdp: str = Field(max_length=MAX_OFFER_BYTES)
    type: Literal["offer"] = "offer"
    token: str = Field(max_length=256)
    role: PeerRole = "worker"
    admin_token: str | None = Field(None, max_length=256)


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


class EpisodeReport(BaseModel):
    """What a teleop server POSTs to the coordinator for every stored episode."""

    model_config = ConfigDict(extra="ignore")  # newer teleop servers may say more

    session_id: str = Field(max_length=64)
    worker_id: str = Field(max_length=64)
    episode: int = Field(ge=0)
    episode_id: str = Field(min_length=1, max_length=64)
    outcome: Outcome
    steps: int = Field(ge=0)
    duration_s: float = Field(ge=0)
    uri: str = Field(max_length=4096)
    telemetry: dict[str, Any] = Field(default_factory=dict)
    device: DeviceKind | None = Field(
        None, description="the device that drove the episode, when the server knows it"
    )
