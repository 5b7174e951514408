"""Crash recovery: finish, as ``crash``, every episode whose recorder died with it.

A live recorder holds ``flock`` on its log, so recovery never touches an episode that is still
being recorded, and the lock dies with a killed process.
"""

from __future__ import annotations

import fcntl
import logging
import os
from pathlib import Path

from crowdteleop.recording.episode_file import (
    EPISODE_SUFFIX,
    CorruptEpisodeError,
    is_readable,
    write_episode,
)
from crowdteleop.recording.storage import fsync_directory
from crowdteleop.recording.wal_codec import WAL_SUFFIX
from crowdteleop.recording.wal_reader import parse_wal

log = logging.getLogger(__name__)


def recover_orphans(directory: Path) -> list[Path]:
    """Finalize, with outcome "crash", every log no live recorder holds; returns the files.

    A log whose episode file already exists (a crash between the file's rename and the log's
    removal), or that holds no step (a crash before its first flush), is simply removed. A log
    with a damaged header is renamed ``*.wal.corrupt`` and kept for a person to look at. Stale
    temporary files are removed.
    """
    directory = Path(directory)
    if not directory.is_dir():
        return []
    recovered = []
    for wal in sorted(directory.glob(f"*{WAL_SUFFIX}")):
        try:
            path = _recover_one(wal)
        except OSError as error:  # e.g. a full disk: the log stays for the next attempt
            log.error("could not recover %s: %s", wal, error)
            continue
        if path is not None:
            recovered.append(path)
    for tmp in directory.glob(f".*{EPISODE_SUFFIX}.tmp"):
        if not (directory / (tmp.name[1 : -len(EPISODE_SUFFIX) - 4] + WAL_SUFFIX)).exists():
            tmp.unlink(missing_ok=True)  # its log is gone: a leftover of a finished episode
    for tmp in directory.glob(f".*{WAL_SUFFIX}.*.tmp"):
        _remove_if_unlocked(tmp)  # a log that never got its name holds no steps
    return recovered


def _recover_one(wal: Path) -> Path | None:
    try:
        fd = os.open(wal, os.O_RDONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return None  # a live recorder holds it
        if os.fstat(fd).st_nlink == 0:
            return None  # finalized while we waited for the lock
        with os.fdopen(os.dup(fd), "rb") as file:
            data = file.read()
        try:
            partial = parse_wal(data, wal)
        except CorruptEpisodeError as error:
            log.warning("cannot recover %s (%s); kept as %s.corrupt", wal, error, wal.name)
            wal.rename(wal.with_name(wal.name + ".corrupt"))
            return None
        path = wal.with_name(partial.episode_id + EPISODE_SUFFIX)
        if len(partial.actions) == 0 and not is_readable(path):
            # Died before its first flush: nothing to keep, and an episode without steps
            # would only make `dataset build` stop on it.
            log.info("%s holds no steps: removed", wal)
            wal.unlink()
            fsync_directory(wal.parent)
            return None
        if not is_readable(path):
            extra = {"ignored_tail_bytes": partial.ignored_tail_bytes}
            write_episode(path, partial, "crash", extra, recovered=True)
        wal.unlink()
        fsync_directory(wal.parent)
        return path
    finally:
        os.close(fd)


def _remove_if_unlocked(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except FileNotFoundError:
        return
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        path.unlink(missing_ok=True)
    except BlockingIOError:
        pass
    finally:
        os.close(fd)
