"""Demonstration data: recording, storage (local, S3 behind a spool), datasets, video."""

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
from crowdteleop.data.s3 import S3Config, S3Storage, StorageAccessError, StorageUnavailableError
from crowdteleop.data.spool import SpooledStorage
from crowdteleop.data.storage import (
    EpisodeStorage,
    InvalidKeyError,
    KeyExistsError,
    LocalDirectoryStorage,
    ObjectNotFoundError,
    StorageError,
)
from crowdteleop.data.stores import StorageConfig, open_storage

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
    "S3Config",
    "S3Storage",
    "SpooledStorage",
    "StepRecord",
    "StorageAccessError",
    "StorageConfig",
    "StorageError",
    "StorageUnavailableError",
    "open_storage",
    "read_episode",
    "read_partial",
    "recover_orphans",
]
