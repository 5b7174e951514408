"""Choosing a store from configuration: a local directory, or S3 behind a local spool."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from crowdteleop.recording.s3 import S3Config, S3Storage
from crowdteleop.recording.spool import SpooledStorage
from crowdteleop.recording.storage import EpisodeStorage, LocalDirectoryStorage

SavedWhen = Literal["stored", "spooled"]


class StorageConfig(BaseModel):
    """Where finished episodes go.

    ``saved_when`` decides when the teleop server tells the worker "saved": ``stored`` (the
    default, and the issue's rule) once the object store confirmed the upload, waiting up to
    ``store_wait_s``; ``spooled`` once the fsync'd spool copy exists (the upload follows).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["local", "s3"] = "local"
    s3: S3Config | None = None
    spool_directory: Path | None = Field(None, description="default: <recording dir>/spool")
    saved_when: SavedWhen = "stored"
    store_wait_s: float = Field(30.0, gt=0, description="how long 'stored' waits for the store")

    @model_validator(mode="after")
    def _s3_has_its_settings(self) -> StorageConfig:
        if self.kind == "s3" and self.s3 is None:
            raise ValueError("storage kind 's3' needs s3 settings (bucket, endpoint_url, ...)")
        return self


def open_storage(config: StorageConfig, directory: Path) -> EpisodeStorage:
    """The configured store; ``directory`` is the recording directory (local root, spool)."""
    if config.kind == "local":
        return LocalDirectoryStorage(directory)
    assert config.s3 is not None
    spool = config.spool_directory or Path(directory) / "spool"
    return SpooledStorage(S3Storage(config.s3), spool)
