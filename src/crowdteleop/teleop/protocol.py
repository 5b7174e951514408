"""The message protocol between a teleop server and its clients, defined once.

Every message is a JSON object with ``v`` (protocol version) and ``type``. Inbound messages are
validated strictly: unknown fields, wrong types, NaN / infinity and out-of-range values are
rejected. The browser code loads the JSON Schema of these models from ``/protocol.json``, so
both sides share one definition. ``docs/protocol.md`` describes the channels and flows.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Final, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter, ValidationError, field_validator

from crowdteleop.vocab import ClutchState, DeviceKind, Outcome

PROTOCOL_VERSION: Final = 1

PeerRole = Literal["worker", "phone", "admin"]
Channel = Literal["control", "events", "admin"]
PracticeStage = Literal["off", "running", "done"]  # teleop/practice.py

# Workspace bound for device positions: a phone moves within arm's reach of its start.
MAX_POSITION_M = 10.0
MAX_SEQ = 2**53  # the largest integer a browser's JSON number holds exactly


class _Message(BaseModel):
    """Server-to-client messages: built by our code, so plain (lax) validation suffices."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    v: Literal[1] = PROTOCOL_VERSION


class _Inbound(_Message):
    """Client-to-server messages: strict, so ``1`` is no boolean and ``"1"`` no number."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)


Seq = Annotated[int, Field(ge=0, le=MAX_SEQ)]
ClientTime = Annotated[float, Field(ge=0, le=1e13, description="client clock, milliseconds")]


# --- client -> server -------------------------------------------------------------------


class PoseCommand(_Inbound):
    """The device pose stream (``control`` channel, unordered, no retransmits): latest wins."""

    type: Literal["pose"] = "pose"
    seq: Seq
    client_time_ms: ClientTime
    device: DeviceKind
    position: tuple[float, float, float]
    quaternion: tuple[float, float, float, float] = Field(description="x, y, z, w")
    engaged: bool
    gripper: bool

    @field_validator("position")
    @classmethod
    def _within_reach(cls, value: tuple[float, float, float]) -> tuple[float, float, float]:
        if any(abs(coordinate) > MAX_POSITION_M for coordinate in value):
            raise ValueError(f"position components must be within +-{MAX_POSITION_M} m")
        return value

    @field_validator("quaternion")
    @classmethod
    def _unit_quaternion(
        cls, value: tuple[float, float, float, float]
    ) -> tuple[float, float, float, float]:
        norm = math.sqrt(sum(component * component for component in value))
        if not 0.5 < norm < 1.5:
            raise ValueError(f"quaternion must be (nearly) unit length, norm is {norm:.3g}")
        return value


class ClutchEvent(_Inbound):
    """Clutch pressed or released (``events``, reliable): a release must never be lost."""

    type: Literal["clutch"] = "clutch"
    seq: Seq
    client_time_ms: ClientTime
    device: DeviceKind
    engaged: bool


class GripperEvent(_Inbound):
    type: Literal["gripper"] = "gripper"
    seq: Seq
    client_time_ms: ClientTime
    device: DeviceKind
    closed: bool


class ResetRequest(_Inbound):
    """End the episode (outcome ``reset``) and start a fresh one."""

    type: Literal["reset"] = "reset"


class StartRequest(_Inbound):
    """Resume a stopped session with a fresh episode."""

    type: Literal["start"] = "start"


class StopRequest(_Inbound):
    """End the episode (outcome ``reset``) and pause the simulation until ``start``."""

    type: Literal["stop"] = "stop"


class SkipPractice(_Inbound):
    """End the practice round now (the worker pressed "Skip practice"); nothing if none runs."""

    type: Literal["skip_practice"] = "skip_practice"


class TakeControl(_Inbound):
    """Make this peer's device the one that drives the arm (the switch is explicit)."""

    type: Literal["take_control"] = "take_control"
    device: DeviceKind


class Ping(_Inbound):
    type: Literal["ping"] = "ping"
    id: Seq
    client_time_ms: ClientTime


class Pong(_Inbound):
    """Reply to the server's `ping`: the server measures data-channel RTT with it and, from
    ``client_time_ms``, how far the client's clock is from its own (to date poses)."""

    type: Literal["pong"] = "pong"
    id: Seq
    server_time_s: float = Field(description="the server ping's own time, echoed")
    client_time_ms: ClientTime | None = Field(None, description="client clock when answering")


class VideoStatus(_Inbound):
    """The worker's page saw its video stop (no new frame for ``video_stall_ms``) or resume.
    A stall releases the clutch until the device lets go and presses again."""

    type: Literal["video"] = "video"
    stalled: bool
    gap_ms: Annotated[float, Field(ge=0, le=1e9)] = 0.0


class LatencyReport(_Inbound):
    """Control-to-photon latencies the client measured (ms), for telemetry."""

    type: Literal["latency"] = "latency"
    samples_ms: Annotated[list[Annotated[float, Field(ge=0, le=60_000)]], Field(max_length=100)]
    fps: Annotated[float, Field(ge=0, le=1000)] = 0.0


ControlMessage = PoseCommand
EventMessage = Annotated[
    ClutchEvent
    | GripperEvent
    | ResetRequest
    | StartRequest
    | StopRequest
    | SkipPractice
    | TakeControl
    | Ping
    | Pong
    | VideoStatus
    | LatencyReport,
    Field(discriminator="type"),
]

# --- server -> client -------------------------------------------------------------------


class Hello(_Message):
    type: Literal["hello"] = "hello"
    session_id: str
    peer_id: str
    role: PeerRole
    task: str
    instruction: str
    fps: float
    width: int
    height: int
    controlling_device: DeviceKind | None
    video_stall_ms: float = Field(1000.0, description="a page whose video stops this long says so")
    max_input_age_ms: float = Field(500.0, description="older poses and presses are not applied")


class ErrorEvent(_Message):
    """A rejected message or a failure; ``code`` is stable, ``message`` is for people."""

    type: Literal["error"] = "error"
    code: str
    message: str
    channel: str = ""


class HapticEvent(_Message):
    type: Literal["haptic"] = "haptic"
    intensity: float = Field(ge=0, le=1)
    robot_part: str
    object: str


class TaskStatus(_Message):
    type: Literal["status"] = "status"
    episode: int
    state: Literal["ready", "running", "stopped"]
    elapsed_s: float
    time_limit_s: float
    success: bool
    stage: str
    message: str
    completed: int
    total: int
    controlling_device: DeviceKind | None
    successes: int
    end_effector: tuple[float, float, float]
    video_stalled: bool = Field(False, description="the worker's video stopped: clutch released")
    clutch: ClutchState = Field(
        "no_driver",
        description="whether the arm follows the driving device, and if not why (teleop/clutch.py)",
    )
    practice: PracticeStage = Field(
        "off",
        description="the practice round before episode 1 (nothing recorded): off, running, done",
    )
    practice_left_s: float = Field(
        0.0, ge=0, description="seconds left in it; they count from the first engaged command"
    )
    practice_reached: bool = Field(False, description="it ended with the hand at the target")


class FrameTag(_Message):
    """Frame ``pts`` (90 kHz RTP clock, before the sender's random offset) shows the effect of
    every command up to ``command_seq``: the client pairs it with the decoded frame."""

    type: Literal["frame"] = "frame"
    pts: int
    command_seq: int
    server_time_s: float = Field(description="server wall clock when published, seconds")


class EpisodeEnded(_Message):
    type: Literal["episode"] = "episode"
    episode: int
    outcome: Outcome
    steps: int
    successes: int


class EpisodeSaved(_Message):
    """The episode's recording is durable (fsync'd and confirmed by the store): only now may
    the worker be told their demonstration counts."""

    type: Literal["saved"] = "saved"
    episode: int
    outcome: Outcome
    uri: str


class EpisodeFeedback(_Message):
    """After a demonstration is counted, how it compares with the study's (the coordinator's
    judgement, docs/quality.md): its time, how much of it was idle and how smooth it was,
    each beside the study's median, and one concrete tip."""

    type: Literal["feedback"] = "feedback"
    episode: int
    score: float | None = Field(None, description="0-100 among the study's demonstrations")
    time_s: float
    median_time_s: float | None = None
    idle_percent: float | None = None
    median_idle_percent: float | None = None
    smoother_than_percent: float | None = Field(
        None, description="the share of the study's demonstrations this one is smoother than"
    )
    tip: str = Field(max_length=300)


class PingReply(_Message):
    """The server's answer to a client `ping`, echoing its id and time."""

    type: Literal["pong"] = "pong"
    id: int
    client_time_ms: float = Field(description="the client ping's own time, echoed")


class ServerPing(_Message):
    type: Literal["ping"] = "ping"
    id: int
    server_time_s: float = Field(description="server monotonic clock, seconds")


class Telemetry(_Message):
    type: Literal["telemetry"] = "telemetry"
    loop_hz: float
    jitter_ms: float
    overruns: int
    frames_sent: int
    fps: float
    bitrate_kbps: float
    rtt_ms: float
    errors: dict[str, int]


class PrivilegedState(_Message):
    """Admin channel only: object and end-effector poses for scripted bots. Never to workers."""

    type: Literal["privileged"] = "privileged"
    step: int
    scene: int = Field(description="changes whenever the scene resets")
    command_seq: int = Field(description="the last command applied in this step")
    end_effector: tuple[float, ...]
    objects: dict[str, tuple[float, ...]]


ServerMessage = Annotated[
    Hello
    | ErrorEvent
    | HapticEvent
    | TaskStatus
    | FrameTag
    | EpisodeEnded
    | EpisodeSaved
    | EpisodeFeedback
    | PingReply
    | ServerPing
    | Telemetry
    | PrivilegedState,
    Field(discriminator="type"),
]

_CONTROL: TypeAdapter[ControlMessage] = TypeAdapter(ControlMessage)
_EVENTS: TypeAdapter[EventMessage] = TypeAdapter(EventMessage)
_SERVER: TypeAdapter[ServerMessage] = TypeAdapter(ServerMessage)
_INBOUND: dict[str, TypeAdapter[ControlMessage] | TypeAdapter[EventMessage]] = {
    "control": _CONTROL,
    "events": _EVENTS,
}


class ProtocolError(ValueError):
    """An inbound message was rejected; ``code`` names the kind for error counters."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


def parse_inbound(channel: str, raw: str | bytes, max_bytes: int) -> BaseModel:
    """Validate one client message on `channel`; raise ProtocolError naming the problem."""
    if len(raw) > max_bytes:
        raise ProtocolError("too_large", f"message of {len(raw)} bytes exceeds {max_bytes}")
    adapter = _INBOUND.get(channel)
    if adapter is None:
        raise ProtocolError("channel", f"clients may not send on channel {channel!r}")
    try:
        return adapter.validate_json(raw)
    except ValidationError as exc:
        raise ProtocolError(_classify(exc), _summarize(exc)) from exc


def _classify(exc: ValidationError) -> str:
    """A stable error code per kind of rejection, for counters and clients."""
    kinds = {error["type"] for error in exc.errors()}
    if "json_invalid" in kinds or "json_type" in kinds:
        return "malformed"
    if any(error["loc"][-1:] == ("v",) for error in exc.errors()):
        return "version"
    if kinds & {"union_tag_not_found", "union_tag_invalid"} or any(
        error["loc"] == ("type",) for error in exc.errors()
    ):
        return "unknown_type"
    return "invalid"


def _summarize(exc: ValidationError) -> str:
    parts = []
    for error in exc.errors()[:3]:
        where = ".".join(str(part) for part in error["loc"]) or "message"
        parts.append(f"{where}: {error['msg']}")
    return "; ".join(parts)


def encode(message: BaseModel) -> str:
    return message.model_dump_json()


def parse_server_message(raw: str | bytes) -> BaseModel:
    """Client side: a message the server sent (trusted, but still typed)."""
    return _SERVER.validate_json(raw)


def json_schema() -> dict[str, Any]:
    """The schema the browser code loads: every message each side may send."""
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": "crowdteleop teleop protocol",
        "version": PROTOCOL_VERSION,
        "channels": {
            "control": _CONTROL.json_schema(),
            "events": _EVENTS.json_schema(),
            "server": _SERVER.json_schema(),
        },
    }
