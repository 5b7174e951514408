"""Demonstration data: recording, storage, video."""

from crowdteleop.data.recording import (
    CorruptEpisodeError,
    Episode,
    EpisodeRecorder,
    InvalidRecordError,
    Outcome,
    PartialEpisode,
    RecordingError,
    StepRecord,
    read_episode,
    read_partial,
    recover_orphans,
)
from crowdteleop.data.storage import (
    EpisodeStorage,
    InvalidKeyError,
    KeyExistsError,
    LocalDirectoryStorage,
    ObjectNotFoundError,
    StorageError,
)

__all__ = [
    "CorruptEpisodeError",
    "Episode",
    "EpisodeRecorder",
    "EpisodeStorage",
    "InvalidKeyError",
    "InvalidRecordError",
    "KeyExistsError",
    "LocalDirectoryStorage",
    "ObjectNotFoundError",
    "Outcome",
    "PartialEpisode",
    "RecordingError",
    "StepRecord",
    "StorageError",
    "read_episode",
    "read_partial",
    "recover_orphans",
]
