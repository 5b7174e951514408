"""Step records of the write-ahead log: packed by the recorder's flusher, unpacked by readers.

A step is one "C" record (format version 2): the fixed fields of ``_COMPACT`` (index, times,
reward, success, state and action sizes, flags, the device command's numbers, the contacts'
count and the size of their names), then the raw little-endian float64 bytes of state and
action, the contacts' intensities and NUL-joined names, the step's subtask labels when flag 8
says they follow (``_LABELS_HEAD`` + float64 poses + NUL-joined names), and JSON of whatever did
not fit the packed layout. Logs written before labels existed never set flag 8, so they read
exactly as before. Version 1 logs hold "S" records (``_STEP`` + vectors + JSON of command and
contacts); they are still read.

Packing runs off the control loop (``EpisodeRecorder`` validates a step's numbers when it is
appended and packs it when the buffer is flushed), so nothing here raises on a step that passed
that validation: a command or contact list that cannot be stored as JSON is recorded as a note
naming the problem (and counted by the recorder), never dropped with the step. Likewise a
label that cannot pack (a pose with NaN, a stage or object name that is not NUL-free UTF-8) is
stored as NaN / "" (the object left out: it reads as missing, NaN) and counted.
"""

from __future__ import annotations

import json
import logging
import math
import struct
import zlib
from typing import Any, cast

import numpy as np
import numpy.typing as npt

from crowdteleop.recording.episode_file import (
    CommandRecord,
    InvalidRecordError,
    StepLabels,
    StepRecord,
    to_json,
)

log = logging.getLogger(__name__)

WAL_MAGIC = b"CTWAL02\n"
WAL_MAGIC_V1 = b"CTWAL01\n"  # read, never written: steps only as "S" records
WAL_SUFFIX = ".wal"
FRAME = struct.Struct("<II")  # payload length, CRC-32 of payload
_STEP = struct.Struct("<qdddBII")  # index, server_time, step_duration_s, reward, success, S, A
_COMPACT = struct.Struct("<cqdddBIIBqd3d4d?dB7sHI")
_COMMAND_PACKED, _GRIPPER_BOOL, _CONTACTS_PACKED, _LABELS = 1, 2, 4, 8  # flags
# Labels (flag 8), after the contacts: u32 size of the rest of the block, u16 object count K,
# then (1 + K) * 7 float64 (hand, then each object: x y z qx qy qz qw), then UTF-8 of stage,
# relative_to and the K object names, NUL-separated.
_LABELS_HEAD = struct.Struct("<IH")
# A command is packed when it has exactly these keys (in any order, kept) with exact types:
# seq int, client_time_ms float, device one of _DEVICES, position 3 and quaternion 4 floats in
# lists, engaged bool, gripper float or bool; all finite. Anything else is stored as JSON.
_COMMAND_KEYS = ("seq", "client_time_ms", "device", "position", "quaternion", "engaged", "gripper")
# The codes are part of the log format: append, never reorder ("scripted": in-process operators).
_DEVICES = (None, "phone", "keyboard", "vr", "spacemouse", "gamepad", "bot", "scripted")
_DEVICE_CODES = {device: code for code, device in enumerate(_DEVICES)}
_KEY_ORDERS: dict[tuple[str, ...], bytes] = {}  # a command's key tuple -> its order code
_CONTACT_KEYS = ("robot_part", "object", "intensity")
_INT64 = (-(2**63), 2**63)
UNRECORDABLE = "unrecordable"  # the key of the note that stands in for unstorable JSON


def frame(payload: bytes) -> bytes:
    """One record: length and checksum, then the payload."""
    return FRAME.pack(len(payload), zlib.crc32(payload)) + payload


def encode_steps(records: list[StepRecord]) -> tuple[bytes, int]:
    """Validated steps as framed "C" records, and how many parts of them had to become notes."""
    parts: list[bytes] = []
    notes = 0
    for record in records:
        payload, noted = _encode_step(record)
        parts += (FRAME.pack(len(payload), zlib.crc32(payload)), payload)
        notes += noted
    return b"".join(parts), notes


def _encode_step(record: StepRecord) -> tuple[bytes, int]:
    state, action, command, contacts = record.state, record.action, record.command, record.contacts
    flags, numbers = _pack_command(command)
    n_contacts, tail, names_size = _pack_contacts(contacts)
    if n_contacts >= 0:
        flags |= _CONTACTS_PACKED
    notes = 0
    if record.labels is not None:
        flags |= _LABELS
        labels, notes = _pack_labels(record.labels, record.index)
        tail += labels
    if not flags & _COMMAND_PACKED or n_contacts < 0:  # JSON for what did not pack
        rest: dict[str, Any] = {} if flags & _COMMAND_PACKED else {"command": command}
        if n_contacts < 0:
            n_contacts, rest["contacts"] = 0, contacts
        json_tail, json_notes = _json_or_notes(rest, record.index)
        tail += json_tail
        notes += json_notes
    fields = _COMPACT.pack(
        b"C",
        record.index,
        float(record.server_time),
        float(record.step_duration_s),
        float(record.reward),
        bool(record.success),
        state.size,
        action.size,
        flags,
        *numbers,
        n_contacts,
        names_size,
    )
    return b"".join((fields, state.tobytes(), action.tobytes(), tail)), notes


def _pack_labels(labels: StepLabels, index: int) -> tuple[bytes, int]:
    """The labels block, and how many of its parts had to be stored as "" / NaN / left out."""
    notes = 0
    texts = [_label_text(labels.stage), _label_text(labels.relative_to)]
    notes += (texts[0] != labels.stage) + (texts[1] != labels.relative_to)
    names: list[str] = []
    poses = [labels.hand_pose]
    for name, pose in labels.object_poses.items():
        if _label_text(name) != name or name in ("", ".") or len(names) == 0xFFFF:
            notes += 1  # left out: read back as missing at this step
            continue
        names.append(name)
        poses.append(pose)
    values = _pose_rows(poses)
    if not math.isfinite(values.sum()):  # rare (or an overflow): store NaN for a bad pose
        finite = np.isfinite(values).all(axis=1)
        values[~finite] = math.nan
        notes += int(np.count_nonzero(~finite))
    if notes:
        log.error("step %d: %d label part(s) could not be stored as given", index, notes)
    body = values.tobytes() + "\x00".join(texts + names).encode()
    return _LABELS_HEAD.pack(len(body), len(names)) + body, notes


def _label_text(text: Any) -> str:
    """A stage or name as packed: NUL-free UTF-8 strings as given, anything else ""."""
    if type(text) is not str or "\x00" in text:
        return ""
    try:
        text.encode()
    except UnicodeEncodeError:  # lone surrogates
        return ""
    return text


def _pose_rows(poses: list[Any]) -> npt.NDArray[np.float64]:
    """Validated (7,) poses as a fresh little-endian (len, 7) array (NaN if, against
    validation, they are not poses)."""
    try:
        return np.concatenate(poses, dtype="<f8").reshape(len(poses), 7)
    except (TypeError, ValueError):
        return np.full((len(poses), 7), math.nan)


def _unpack_labels(payload: bytes, offset: int) -> tuple[StepLabels, int]:
    """The labels block at ``offset``, and the offset after it."""
    size, count = _LABELS_HEAD.unpack_from(payload, offset)
    start, end = offset + _LABELS_HEAD.size, offset + _LABELS_HEAD.size + size
    if end > len(payload):
        raise ValueError("labels run past the record")
    poses = np.frombuffer(payload, "<f8", 7 * (1 + count), start).reshape(-1, 7).copy()
    texts = payload[start + poses.nbytes : end].decode().split("\x00")
    if len(texts) != 2 + count:
        raise ValueError("label names do not match their count")
    labels = StepLabels(
        stage=texts[0],
        relative_to=texts[1],
        hand_pose=poses[0],
        object_poses=dict(zip(texts[2:], poses[1:], strict=True)),
    )
    return labels, end


def _json_or_notes(rest: dict[str, Any], index: int) -> tuple[bytes, int]:
    """JSON of the parts that did not pack; a part JSON refuses becomes a note saying why."""
    try:
        return to_json(rest, "step").encode(), 0
    except InvalidRecordError:
        pass
    notes = 0
    for key, value in rest.items():  # replaces values only: safe while iterating
        try:
            to_json(value, key)
        except InvalidRecordError as error:
            log.error("step %d: %s; recorded as a note", index, error)
            note = {UNRECORDABLE: str(error)}
            rest[key] = note if key == "command" else [note]
            notes += 1
    return to_json(rest, "step").encode(), notes


def _pack_command(command: CommandRecord) -> tuple[int, tuple[Any, ...]]:
    """(flags, the _COMPACT fields) of a command that packs exactly, else (0, zeros)."""
    order = _KEY_ORDERS.get(tuple(command)) or _key_order(command)
    if order is None:
        return 0, _NO_COMMAND
    seq, t, gripper, engaged = (
        command["seq"],
        command["client_time_ms"],
        command["gripper"],
        command["engaged"],
    )
    position, quaternion = command["position"], command["quaternion"]
    try:
        p0, p1, p2 = position
        q0, q1, q2, q3 = quaternion
        device = _DEVICE_CODES[command["device"]]
    except (TypeError, ValueError, KeyError):
        return 0, _NO_COMMAND
    if not (
        type(seq) is int
        and _INT64[0] <= seq < _INT64[1]
        and type(engaged) is bool
        and type(position) is list is type(quaternion)
        and type(t) is float is type(p0) is type(p1) is type(p2)
        and float is type(q0) is type(q1) is type(q2) is type(q3)
        and math.isfinite(t + p0 + p1 + p2 + q0 + q1 + q2 + q3)  # NaN and inf: JSON refuses
    ):
        return 0, _NO_COMMAND
    if type(gripper) is bool:
        flags = _COMMAND_PACKED | _GRIPPER_BOOL
    elif type(gripper) is float and math.isfinite(gripper):
        flags = _COMMAND_PACKED
    else:
        return 0, _NO_COMMAND
    return flags, (seq, t, p0, p1, p2, q0, q1, q2, q3, engaged, float(gripper), device, order)


_NO_COMMAND = (0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, False, 0.0, 0, bytes(7))


def _key_order(command: CommandRecord) -> bytes | None:
    """The order of a command's keys as indices into _COMMAND_KEYS, if they are those keys."""
    keys = tuple(command)
    if len(keys) != len(_COMMAND_KEYS) or set(keys) != set(_COMMAND_KEYS):
        return None
    order = bytes(_COMMAND_KEYS.index(key) for key in keys)
    _KEY_ORDERS[keys] = order  # at most 7! entries
    return order


def _pack_contacts(contacts: list[Any]) -> tuple[int, bytes, int]:
    """(count, intensities as float64 + NUL-joined UTF-8 names, size of the names) if they
    pack exactly, else (-1, b"", 0)."""
    if not contacts:
        return 0, b"", 0
    names: list[str] = []
    intensities = []
    for contact in contacts:
        fields = _contact_fields(contact)
        if fields is None:
            return _NOT_PACKED
        part, other, intensity = fields
        names += (part, other)
        intensities.append(intensity)
    joined = "\x00".join(names)
    if len(intensities) > 0xFFFF or joined.count("\x00") != len(names) - 1:
        return _NOT_PACKED  # too many, or a NUL inside a name
    if not math.isfinite(sum(intensities)):
        return _NOT_PACKED
    try:
        encoded = joined.encode()
    except UnicodeEncodeError:  # lone surrogates: JSON escapes them
        return _NOT_PACKED
    values = struct.pack(f"<{len(intensities)}d", *intensities)
    return len(intensities), values + encoded, len(encoded)


_NOT_PACKED = -1, b"", 0


def _contact_fields(contact: Any) -> tuple[str, str, float] | None:
    """A contact's robot part, object and intensity if it is exactly a packable contact: a dict
    of ``_CONTACT_KEYS`` in that order, two strings and a float."""
    if type(contact) is not dict or tuple(contact) != _CONTACT_KEYS:
        return None
    part, other, intensity = contact.values()
    if not (type(part) is str is type(other) and type(intensity) is float):
        return None
    return part, other, intensity


def decode_step(payload: bytes, index: int) -> StepRecord:
    if payload[:1] == b"C":
        return _decode_compact(payload, index)
    if payload[:1] != b"S":
        raise ValueError("not a step record")
    fields = _STEP.unpack_from(payload, 1)
    if fields[0] != index:
        raise ValueError(f"step {fields[0]} where step {index} was due")
    n_state, n_action = fields[5:]
    start = 1 + _STEP.size
    vectors = np.frombuffer(payload, "<f8", n_state + n_action, start).copy()
    extras = json.loads(payload[start + 8 * (n_state + n_action) :])
    return StepRecord(
        index=index,
        state=vectors[:n_state],
        action=vectors[n_state:],
        command=extras["command"],
        server_time=fields[1],
        step_duration_s=fields[2],
        reward=fields[3],
        success=bool(fields[4]),
        contacts=extras["contacts"],
    )


def _decode_compact(payload: bytes, index: int) -> StepRecord:
    (_, number, server_time, duration, reward, success, n_state, n_action, flags, seq, t,
     p0, p1, p2, q0, q1, q2, q3, engaged, gripper, device, order, n_contacts, names_size,
     ) = _COMPACT.unpack_from(payload)  # fmt: skip
    if number != index:
        raise ValueError(f"step {number} where step {index} was due")
    offset = _COMPACT.size
    vectors = np.frombuffer(payload, "<f8", n_state + n_action, offset).copy()
    offset += 8 * (n_state + n_action)
    contacts: list[dict[str, Any]] = []
    if n_contacts:
        intensities = struct.unpack_from(f"<{n_contacts}d", payload, offset)
        offset += 8 * n_contacts
        names = payload[offset : offset + names_size].decode().split("\x00")
        offset += names_size
        if len(names) != 2 * n_contacts:
            raise ValueError("contact names do not match their count")
        contacts = [
            {"robot_part": names[2 * i], "object": names[2 * i + 1], "intensity": intensities[i]}
            for i in range(n_contacts)
        ]
    labels = None
    if flags & _LABELS:
        labels, offset = _unpack_labels(payload, offset)
    rest = json.loads(payload[offset:]) if offset < len(payload) else {}
    if flags & _COMMAND_PACKED:
        values = {
            "seq": seq,
            "client_time_ms": t,
            "device": _DEVICES[device],
            "position": [p0, p1, p2],
            "quaternion": [q0, q1, q2, q3],
            "engaged": engaged,
            "gripper": bool(gripper) if flags & _GRIPPER_BOOL else gripper,
        }
        command = cast(
            CommandRecord, {_COMMAND_KEYS[key]: values[_COMMAND_KEYS[key]] for key in order}
        )
    else:
        command = cast(CommandRecord, rest["command"])  # stored as given: the recorder kept it
    return StepRecord(
        index=index,
        state=vectors[:n_state],
        action=vectors[n_state:],
        command=command,
        server_time=server_time,
        step_duration_s=duration,
        reward=reward,
        success=bool(success),
        contacts=contacts if flags & _CONTACTS_PACKED else rest["contacts"],
        labels=labels,
    )
