"""Where finished episodes go: a storage interface, and a local directory that implements it.

Keys are S3-style relative paths (``lift/2024-05-01/ep-42.hdf5``); ``put`` returns a URI that
``get`` accepts. ``crowdteleop.recording.s3`` puts S3-compatible object storage behind the same
interface and ``crowdteleop.recording.spool`` a local spool in front of it.
"""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import uuid
from pathlib import Path
from typing import Protocol, runtime_checkable
from urllib.parse import unquote, urlparse

from crowdteleop.errors import CrowdteleopError

MAX_KEY_LENGTH = 1024  # S3's limit, so a key valid here is valid there


class StorageError(CrowdteleopError, RuntimeError):
    """The store could not do what was asked."""


class StorageUnavailableError(StorageError):
    """The store cannot be reached or answered with a server error: worth retrying later."""


class InvalidKeyError(CrowdteleopError, ValueError):
    """A key or URI that does not name an object of this store."""


class KeyExistsError(StorageError):
    """A key already holds different content; stored episodes are never replaced."""


class ObjectNotFoundError(StorageError, FileNotFoundError):
    """No object under that URI."""


@runtime_checkable
class EpisodeStorage(Protocol):
    """What the teleop server and dataset tools need from a store of episode files."""

    def put(self, local_path: Path, key: str) -> str:
        """Store a copy of ``local_path`` under ``key`` durably; returns its URI.

        Idempotent: putting the same content under the same key again returns the same URI.
        """
        ...

    def get(self, uri: str, local_path: Path) -> Path:
        """Copy the object at ``uri`` to ``local_path`` (atomically); returns ``local_path``."""
        ...

    def list(self, prefix: str = "") -> list[str]:
        """Keys starting with ``prefix``, sorted."""
        ...

    def uri(self, key: str) -> str:
        """The URI of ``key`` (whether or not it is stored)."""
        ...

    def wait_durable(self, key: str, timeout_s: float) -> None:
        """Return once the object at ``key`` is in its final store; raise
        ``StorageUnavailableError`` if that takes longer than ``timeout_s``. A store whose
        ``put`` is already final returns at once; a spool waits for its upload."""
        ...

    def pending_count(self) -> int:
        """Objects waiting to reach their final store: a spool's backlog (0 for a store
        whose ``put`` is already final)."""
        ...

    def close(self) -> None:
        """Stop background work (a spool's upload thread); pending objects stay on disk."""
        ...


class LocalDirectoryStorage:
    """``file://`` objects under a root directory.

    Each put writes a hidden temporary file next to the target, fsyncs it, publishes it with
    ``os.link`` (atomic like a rename, but it fails instead of replacing an existing object,
    so two writers of one key cannot clobber each other) and fsyncs the directories: once
    ``put`` returns, the object survives a power loss.
    """

    def __init__(self, root: Path) -> None:
        self.root = Path(root).resolve()
        self.root.mkdir(parents=True, exist_ok=True)

    def uri(self, key: str) -> str:
        return self._path(key).as_uri()

    def wait_durable(self, key: str, timeout_s: float) -> None:
        """``put`` fsync'd the object and its directories: nothing to wait for."""

    def pending_count(self) -> int:
        return 0  # a put here is final

    def close(self) -> None:
        """Nothing runs in the background."""

    def put(self, local_path: Path, key: str) -> str:
        source = Path(local_path)
        target = self._path(key)
        if not source.is_file():
            raise ObjectNotFoundError(f"nothing to store: {source} is not a file")
        if target.exists():
            return self._existing(source, target, key)
        target.parent.mkdir(parents=True, exist_ok=True)
        tmp = _copy_to_temp(source, target)
        try:
            os.link(tmp, target)
        except FileExistsError:
            return self._existing(source, target, key)  # another writer won the race
        finally:
            tmp.unlink(missing_ok=True)
        for directory in (target.parent, *target.parent.parents):
            fsync_directory(directory)
            if directory == self.root:
                break
        return target.as_uri()

    def get(self, uri: str, local_path: Path) -> Path:
        source = self._path_of_uri(uri)
        if not source.is_file():
            raise ObjectNotFoundError(f"no object at {uri}")
        local_path = Path(local_path)
        local_path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _copy_to_temp(source, local_path)
        try:
            os.replace(tmp, local_path)
        finally:
            tmp.unlink(missing_ok=True)
        return local_path

    def list(self, prefix: str = "") -> list[str]:
        keys: list[str] = []
        for directory, subdirectories, files in os.walk(self.root):
            subdirectories[:] = [name for name in subdirectories if not name.startswith(".")]
            keys.extend(
                Path(directory, name).relative_to(self.root).as_posix()
                for name in files
                if not name.startswith(".")
            )
        return sorted(key for key in keys if key.startswith(prefix))

    def _existing(self, source: Path, target: Path, key: str) -> str:
        if file_sha256(source) != file_sha256(target):
            raise KeyExistsError(f"{key!r} already holds different content in {self.root}")
        return target.as_uri()

    def _path(self, key: str) -> Path:
        return self.root.joinpath(*validate_key(key).split("/"))

    def _path_of_uri(self, uri: str) -> Path:
        parsed = urlparse(uri)
        if parsed.scheme != "file" or parsed.netloc not in ("", "localhost"):
            raise InvalidKeyError(f"{uri!r} is not a file:// URI")
        path = Path(unquote(parsed.path))
        try:
            key = path.relative_to(self.root).as_posix()
        except ValueError as error:
            raise InvalidKeyError(f"{uri!r} is outside this store ({self.root})") from error
        return self._path(key)


def validate_key(key: str) -> str:
    """``key`` if it is a relative path of '/'-separated names, else ``InvalidKeyError``."""
    if not isinstance(key, str) or not key or len(key) > MAX_KEY_LENGTH:
        raise InvalidKeyError(f"key must be 1-{MAX_KEY_LENGTH} characters, got {key!r}")
    parts = key.split("/")
    if "\\" in key or "\x00" in key or any(not p or p.startswith(".") for p in parts):
        raise InvalidKeyError(
            f"bad key {key!r}: a relative path of '/'-separated names, none empty or "
            "starting with '.' (hidden names are the store's temporary files)"
        )
    return key


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file's content, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as file:
        while chunk := file.read(1 << 20):
            digest.update(chunk)
    return digest.hexdigest()


def _copy_to_temp(source: Path, target: Path) -> Path:
    """A fsync'd copy of ``source`` under a hidden name next to ``target``."""
    tmp = target.with_name(f".{target.name}.{uuid.uuid4().hex}.tmp")
    try:
        with open(source, "rb") as reader, open(tmp, "xb") as writer:
            shutil.copyfileobj(reader, writer, 1 << 20)
            writer.flush()
            os.fsync(writer.fileno())
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return tmp


def fsync_directory(directory: Path) -> None:
    """Make a create, rename or unlink in ``directory`` durable."""
    fd = os.open(directory, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def disk_is_full(error: BaseException) -> bool:
    """Whether a recording or storing failure comes down to a full disk (ENOSPC), raised
    directly or as the cause of a RecordingError."""
    cause = error.__cause__ if isinstance(error.__cause__, OSError) else error
    return isinstance(cause, OSError) and cause.errno == errno.ENOSPC
