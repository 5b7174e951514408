"""A local spool in front of a remote store: demonstrations wait on disk while it is away.

``put`` makes a fsync'd copy in the spool directory (``<id>.hdf5``, then its manifest
``<id>.json`` naming the key and SHA-256; an entry exists once its manifest does) and returns
at once; a background thread uploads entries oldest first, with exponential backoff while the
store is unreachable, and removes each only after the store confirmed it. A new process on the
same directory picks up where the last one stopped: entries survive restarts and crashes.

Exactly once: an entry is removed after its upload is confirmed, so a crash in between uploads
it again, and the store's idempotent keys turn that second upload into a no-op (same content,
same key, same URI). ``wait`` lets a caller block until a given key is confirmed.
"""

from __future__ import annotations

import builtins
import hashlib
import json
import logging
import os
import random
import shutil
import threading
import time
import uuid
from dataclasses import dataclass
from pathlib import Path

from crowdteleop.recording.s3 import StorageAccessError, backoff_delays
from crowdteleop.recording.storage import (
    EpisodeStorage,
    KeyExistsError,
    StorageError,
    StorageUnavailableError,
    file_sha256,
    fsync_directory,
    validate_key,
)

log = logging.getLogger(__name__)

STALE_TEMP_S = 600.0  # a half-written entry this old belongs to a dead process
CONFLICTS = "conflicts"  # entries the store holds different content for: kept for a person


@dataclass(frozen=True)
class SpoolEntry:
    key: str
    sha256: str
    data: Path
    manifest: Path


class SpooledStorage:
    """``EpisodeStorage`` that is durable locally first and remote eventually."""

    def __init__(
        self,
        remote: EpisodeStorage,
        directory: Path,
        backoff_base_s: float = 0.5,
        backoff_max_s: float = 30.0,
        start: bool = True,
    ) -> None:
        self.remote = remote
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self._delay = backoff_delays(backoff_base_s, backoff_max_s, random.Random())
        self._changed = threading.Condition()
        self._wake = threading.Event()
        self._stop = threading.Event()
        self.uploaded = 0
        self.failures = 0
        self.last_error: str | None = None
        self._remove_stale_temporaries()
        self._thread: threading.Thread | None = None
        if start:
            self.start()

    # --- the interface ----------------------------------------------------------------------

    def uri(self, key: str) -> str:
        return self.remote.uri(key)

    def put(self, local_path: Path, key: str) -> str:
        """Spool a fsync'd copy (durable once this returns) and queue its upload."""
        validate_key(key)
        source = Path(local_path)
        sha256 = file_sha256(source)
        entry = self._entry(key)
        existing = self._read_manifest(entry.manifest)
        if existing is not None:
            if existing.sha256 != sha256:
                raise KeyExistsError(f"{key!r} is spooled with different content")
            return self.uri(key)
        tmp = self.directory / f".{entry.data.name}.{uuid.uuid4().hex}.tmp"
        try:
            with open(source, "rb") as reader, open(tmp, "xb") as writer:
                shutil.copyfileobj(reader, writer, 1 << 20)
                writer.flush()
                os.fsync(writer.fileno())
            os.replace(tmp, entry.data)
            _write_json_durably(entry.manifest, {"key": key, "sha256": sha256, "at": time.time()})
        finally:
            tmp.unlink(missing_ok=True)
        fsync_directory(self.directory)
        self._wake.set()
        return self.uri(key)

    def get(self, uri: str, local_path: Path) -> Path:
        for entry in self.pending_entries():
            if self.uri(entry.key) == uri:
                shutil.copyfile(entry.data, local_path)
                return Path(local_path)
        return self.remote.get(uri, local_path)

    def list(self, prefix: str = "") -> list[str]:
        pending = {key for key in self.pending() if key.startswith(prefix)}
        return sorted(pending.union(self.remote.list(prefix)))

    # --- the spool ----------------------------------------------------------------------------

    def pending(self) -> builtins.list[str]:  # `list` here is the method above
        """Keys spooled and not yet confirmed by the store, oldest first."""
        return [entry.key for entry in self.pending_entries()]

    def pending_entries(self) -> builtins.list[SpoolEntry]:
        entries = []
        for manifest in self.directory.glob("*.json"):
            entry = self._read_manifest(manifest)
            if entry is not None:
                entries.append((manifest.stat().st_mtime if manifest.exists() else 0.0, entry))
        return [entry for _, entry in sorted(entries, key=lambda pair: pair[0])]

    def is_pending(self, key: str) -> bool:
        return self._entry(key).manifest.exists()

    def wait(self, key: str, timeout_s: float) -> bool:
        """Block until the store confirmed ``key`` (True) or ``timeout_s`` passed (False)."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while self.is_pending(key):
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._wake.set()
                self._changed.wait(min(remaining, 0.2))  # 0.2: another process may upload it
        return True

    def pending_count(self) -> int:
        return len(self.pending_entries())

    def wait_durable(self, key: str, timeout_s: float) -> None:
        """The store confirmed ``key`` within ``timeout_s``, or ``StorageUnavailableError``: the
        object then stays spooled and is uploaded when the store is back."""
        if not self.wait(key, timeout_s):
            raise StorageUnavailableError(
                f"{key} is spooled in {self.directory} but the store did not confirm it within "
                f"{timeout_s:.0f} s ({self.last_error or 'no answer'}); it will be uploaded when "
                "the store is back"
            )

    def drain(self, timeout_s: float) -> bool:
        """Block until nothing is pending (True) or ``timeout_s`` passed (False)."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while self.pending_entries():
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._changed.wait(min(remaining, 0.2))
        return True

    def upload_pending(self) -> int:
        """Try every pending entry once, in this thread; returns how many the store confirmed.
        Raises the first error that stops an upload (the entry stays)."""
        done = 0
        for entry in self.pending_entries():
            self._upload(entry)
            done += 1
        return done

    def start(self) -> None:
        if self._thread is None or not self._thread.is_alive():
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="spool-upload", daemon=True)
            self._thread.start()

    def close(self) -> None:
        """Stop uploading; what is pending stays on disk for the next start."""
        self._stop.set()
        self._wake.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None

    # --- internals ----------------------------------------------------------------------------

    def _run(self) -> None:
        attempt = 0
        while not self._stop.is_set():
            entries = self.pending_entries()
            if not entries:
                self._wake.wait(1.0)
                self._wake.clear()
                continue
            entry = entries[0]
            try:
                for entry in entries:
                    if self._stop.is_set():
                        return
                    self._upload(entry)
                attempt = 0
            except KeyExistsError as error:
                log.error("%s; moved to %s/ for a person to look at", error, CONFLICTS)
                self._set_aside(entry)
            except (StorageError, OSError) as error:
                self.failures += 1
                self.last_error = str(error)
                access = isinstance(error, StorageAccessError)
                delay = self._delay(attempt + (8 if access else 0))
                attempt += 1
                log.warning("spool upload failed (%s); next try in %.1f s", error, delay)
                self._stop.wait(delay)

    def _upload(self, entry: SpoolEntry) -> None:
        self.remote.put(entry.data, entry.key)
        for path in (entry.manifest, entry.data):
            path.unlink(missing_ok=True)
        fsync_directory(self.directory)
        self.uploaded += 1
        with self._changed:
            self._changed.notify_all()

    def _set_aside(self, entry: SpoolEntry) -> None:
        target = self.directory / CONFLICTS
        target.mkdir(exist_ok=True)
        for path in (entry.data, entry.manifest):
            if path.exists():
                os.replace(path, target / path.name)
        fsync_directory(self.directory)

    def _entry(self, key: str) -> SpoolEntry:
        name = hashlib.sha256(key.encode()).hexdigest()[:40]
        return SpoolEntry(key, "", self.directory / f"{name}.hdf5", self.directory / f"{name}.json")

    def _read_manifest(self, manifest: Path) -> SpoolEntry | None:
        try:
            content = json.loads(manifest.read_text())
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as error:
            log.error("unreadable spool manifest %s: %s", manifest, error)
            return None
        entry = self._entry(content["key"])
        return SpoolEntry(content["key"], content["sha256"], entry.data, entry.manifest)

    def _remove_stale_temporaries(self) -> None:
        now = time.time()
        for path in self.directory.iterdir():
            stale = now - path.stat().st_mtime > STALE_TEMP_S
            orphan = path.suffix == ".hdf5" and not path.with_suffix(".json").exists()
            if stale and (path.name.endswith(".tmp") or orphan):
                path.unlink(missing_ok=True)


def _write_json_durably(path: Path, content: dict[str, object]) -> None:
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex}.tmp")
    try:
        with open(tmp, "x") as file:
            json.dump(content, file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
