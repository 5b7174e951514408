"""Reading a write-ahead log back: every step up to the first torn or damaged record.

The format is described in ``crowdteleop.recording.wal``; its constants and step layout live in
``crowdteleop.recording.wal_codec``.
"""

from __future__ import annotations

import json
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from crowdteleop.recording.episode_file import (
    CorruptEpisodeError,
    PartialEpisode,
    StepRecord,
    split_metadata,
    stack_labels,
)
from crowdteleop.recording.wal_codec import FRAME, WAL_MAGIC, WAL_MAGIC_V1, decode_step

_MAX_PAYLOAD = 64 * 1024 * 1024  # larger length fields are garbage, not records


def read_partial(path: Path) -> PartialEpisode:
    """Everything a write-ahead log holds up to its first torn or damaged record."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError as error:
        raise CorruptEpisodeError(f"no write-ahead log at {path}") from error
    return parse_wal(data, path)


def parse_wal(data: bytes, path: Path) -> PartialEpisode:
    if not data.startswith((WAL_MAGIC, WAL_MAGIC_V1)):
        raise CorruptEpisodeError(f"{path} is not a crowdteleop write-ahead log")
    records = _records(data)
    try:
        end, payload = next(records)
        header = _decode_header(payload)
    except (StopIteration, ValueError, KeyError, TypeError) as error:
        raise CorruptEpisodeError(
            f"{path}: the log's header is damaged, nothing is recoverable"
        ) from error
    steps: list[StepRecord] = []
    for record_end, payload in records:
        try:
            steps.append(decode_step(payload, len(steps)))
        except (ValueError, KeyError, TypeError, IndexError, struct.error):
            break  # checksum fine but not our step: a bug or a foreign tail; stop trusting
        end = record_end
    metadata, model_xml, env_args = split_metadata(header["metadata"])
    return PartialEpisode(
        episode_id=header["episode_id"],
        metadata=metadata,
        model_xml=model_xml,
        env_args=env_args,
        created_at=header["created_at"],
        states=_stack([step.state for step in steps]),
        actions=_stack([step.action for step in steps]),
        server_time=np.array([step.server_time for step in steps], dtype=float),
        step_duration_s=np.array([step.step_duration_s for step in steps], dtype=float),
        rewards=np.array([step.reward for step in steps], dtype=float),
        success=np.array([step.success for step in steps], dtype=bool),
        commands=[step.command for step in steps],
        contacts=[step.contacts for step in steps],
        labels=stack_labels([step.labels for step in steps]),
        ignored_tail_bytes=len(data) - end,
    )


def _records(data: bytes) -> Iterator[tuple[int, bytes]]:
    """(end offset, payload) of each whole record whose checksum holds, up to the first not."""
    offset = len(WAL_MAGIC)
    while offset + FRAME.size <= len(data):
        length, crc = FRAME.unpack_from(data, offset)
        end = offset + FRAME.size + length
        if length > _MAX_PAYLOAD or end > len(data):
            return  # torn: the record was being written
        payload = data[offset + FRAME.size : end]
        if zlib.crc32(payload) != crc:
            return  # damaged: nothing after it can be trusted
        yield end, payload
        offset = end


def _decode_header(payload: bytes) -> dict[str, Any]:
    if payload[:1] != b"H":
        raise ValueError("the first record is not a header")
    header: dict[str, Any] = json.loads(payload[1:])
    if not isinstance(header["episode_id"], str) or not isinstance(header["metadata"], dict):
        raise ValueError("header without episode id or metadata")
    float(header["created_at"])
    return header


def _stack(rows: list[npt.NDArray[np.float64]]) -> npt.NDArray[np.float64]:
    return np.stack(rows) if rows else np.zeros((0, 0))
