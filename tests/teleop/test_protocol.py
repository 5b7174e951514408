"""The teleop protocol (crowdteleop.teleop.protocol): strict parsing of what clients send, error
codes, and the JSON Schema the browser loads."""

from __future__ import annotations

import json

import pytest
from pydantic import BaseModel, ValidationError

from crowdteleop.teleop import protocol
from crowdteleop.teleop.protocol import (
    ClutchEvent,
    PoseCommand,
    ProtocolError,
    json_schema,
    parse_inbound,
    parse_server_message,
)
from tests.fixtures.poses import POSE


def _code(channel: str, raw: str | bytes, max_bytes: int = 4096) -> str:
    with pytest.raises(ProtocolError) as caught:
        parse_inbound(channel, raw, max_bytes)
    return caught.value.code


def test_a_valid_pose_parses():
    message = parse_inbound("control", json.dumps(POSE), 4096)
    assert isinstance(message, PoseCommand) and message.position == (0.0, 0.1, 0.0)


@pytest.mark.parametrize(
    ("raw", "code"),
    [
        ("{", "malformed"),
        (b"\xff\xfe", "malformed"),
        ("[1, 2]", "invalid"),
        (json.dumps({**POSE, "v": 2}), "version"),
        (json.dumps({**POSE, "type": "teleport"}), "unknown_type"),
        (json.dumps({**POSE, "spare": 1}), "invalid"),
        (json.dumps({**POSE, "engaged": 1}), "invalid"),
        (json.dumps({**POSE, "seq": "1"}), "invalid"),
        (json.dumps({**POSE, "seq": -1}), "invalid"),
        (json.dumps({**POSE, "position": [float("nan"), 0, 0]}), "invalid"),
        (json.dumps({**POSE, "position": [float("inf"), 0, 0]}), "invalid"),
        (json.dumps({**POSE, "position": [50.0, 0, 0]}), "invalid"),
        (json.dumps({**POSE, "quaternion": [0, 0, 0, 0]}), "invalid"),
        (json.dumps({**POSE, "device": "toaster"}), "invalid"),
        (json.dumps({k: v for k, v in POSE.items() if k != "seq"}), "invalid"),
    ],
)
def test_bad_pose_messages_are_rejected_with_a_code(raw, code):
    assert _code("control", raw) == code


def test_oversized_messages_and_foreign_channels_are_rejected():
    assert _code("control", json.dumps(POSE), max_bytes=64) == "too_large"
    assert _code("admin", json.dumps(POSE)) == "channel"


def test_events_channel_takes_events_not_poses():
    assert _code("events", json.dumps(POSE)) == "unknown_type"
    clutch = {
        "v": 1,
        "type": "clutch",
        "seq": 2,
        "client_time_ms": 0,
        "device": "phone",
        "engaged": False,
    }
    assert isinstance(parse_inbound("events", json.dumps(clutch), 4096), ClutchEvent)


def _listed(channel_schema: dict) -> set[str]:
    """The message types a channel's schema lists: its discriminator's, or its one model's."""
    if "discriminator" in channel_schema:
        return set(channel_schema["discriminator"]["mapping"])
    return {channel_schema["properties"]["type"]["const"]}


def _recognised(channel: str, kind: str) -> bool:
    """Whether the real parser of `channel` knows messages of type `kind`: a bare message of a
    known type fails on its missing fields, one of an unknown type on its type."""
    raw = json.dumps({"v": 1, "type": kind})
    if channel == "server":  # what a client takes from the server
        try:
            parse_server_message(raw)
        except ValidationError as exc:
            unknown = {"union_tag_invalid", "union_tag_not_found"}
            return not {error["type"] for error in exc.errors()} & unknown
        return True
    try:
        parse_inbound(channel, raw, 4096)
    except ProtocolError as exc:
        return exc.code != "unknown_type"
    return True


def test_the_schema_covers_every_channel():
    """Per channel, the schema lists exactly the message types the real parsers recognise
    there (of every type the protocol defines, and one it does not)."""
    schema = json_schema()
    assert set(schema["channels"]) == {"control", "events", "server"}
    assert schema["version"] == 1
    defined = {
        model.model_fields["type"].default
        for model in vars(protocol).values()
        if isinstance(model, type) and issubclass(model, BaseModel) and "type" in model.model_fields
    }
    assert {"pose", "clutch", "hello", "privileged"} <= defined
    for channel, channel_schema in schema["channels"].items():
        recognised = {kind for kind in defined | {"teleport"} if _recognised(channel, kind)}
        assert _listed(channel_schema) == recognised, channel
