"""Crash-safe episode recording: a write-ahead log while the episode runs, one HDF5 file after.

The pieces live in ``crowdteleop.data.wal`` (the recorder, its log, crash recovery) and
``crowdteleop.data.episode_file`` (the finished file); this module keeps their public names
importable from one place. See ``docs/recording.md``.
"""

from crowdteleop.data.episode_file import (
    DEMO,
    EPISODE_SUFFIX,
    FILE_FORMAT,
    FILE_FORMAT_VERSION,
    OUTCOMES,
    CorruptEpisodeError,
    Episode,
    EpisodeData,
    InvalidRecordError,
    Outcome,
    PartialEpisode,
    RecordingError,
    StepRecord,
    read_episode,
)
from crowdteleop.data.wal import (
    WAL_MAGIC,
    WAL_SUFFIX,
    EpisodeRecorder,
    read_partial,
    recover_orphans,
)

__all__ = [
    "DEMO",
    "EPISODE_SUFFIX",
    "FILE_FORMAT",
    "FILE_FORMAT_VERSION",
    "OUTCOMES",
    "WAL_MAGIC",
    "WAL_SUFFIX",
    "CorruptEpisodeError",
    "Episode",
    "EpisodeData",
    "EpisodeRecorder",
    "InvalidRecordError",
    "Outcome",
    "PartialEpisode",
    "RecordingError",
    "StepRecord",
    "read_episode",
    "read_partial",
    "recover_orphans",
]
