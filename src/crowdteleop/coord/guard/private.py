"""Files and folders only the coordinator's user may read: the data folder, the database, and
every file holding a secret. Created with their final mode (never chmodded after writing), and
an existing one with a looser mode is tightened, with a warning in the log.

The process umask is left alone: recordings (`episodes/`) keep their usual modes, so a dataset
tool run by another user can read them once an admin opens the data folder to it.
"""

from __future__ import annotations

import contextlib
import logging
import os
import stat
from pathlib import Path

log = logging.getLogger(__name__)

PRIVATE_DIR = 0o700
PRIVATE_FILE = 0o600
_WRITE = os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC | os.O_NOFOLLOW


def tighten(path: Path, mode: int) -> bool:
    """Make `path` no more open than `mode` (if it exists); True if it had to change."""
    try:
        current = stat.S_IMODE(path.lstat().st_mode)
    except FileNotFoundError:
        return False
    if path.is_symlink() or current & ~mode == 0:
        return False
    path.chmod(current & mode)
    log.warning(
        "tightened %s from %04o to %04o: it may hold secrets", path, current, current & mode
    )
    return True


def private_dir(path: Path) -> Path:
    """`path` as a folder of mode 0700 (its missing parents get the usual mode)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        path.mkdir(mode=PRIVATE_DIR)
    except FileExistsError:
        tighten(path, PRIVATE_DIR)
    return path


def write_private(path: Path, data: bytes | str) -> Path:
    """Write `data` to `path`, readable by its owner only from the first byte on.

    An existing file is truncated and its mode set to 0600 before anything is written to it;
    a symlink in its place is refused (`O_NOFOLLOW`)."""
    raw = data.encode() if isinstance(data, str) else data
    fd = os.open(path, _WRITE, PRIVATE_FILE)
    try:
        os.fchmod(fd, PRIVATE_FILE)  # an existing file keeps its mode through O_CREAT
        view = memoryview(raw)
        while view:
            view = view[os.write(fd, view) :]
    finally:
        os.close(fd)
    return path


def open_private_log(path: Path) -> int:
    """A file descriptor appending to `path` (created 0600): a child process's stderr."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND | os.O_CLOEXEC, PRIVATE_FILE)
    os.fchmod(fd, PRIVATE_FILE)
    return fd


def private_sqlite(database: Path) -> None:
    """The database file exists with mode 0600 before SQLite opens it, so its `-wal`, `-shm`
    and `-journal` (which SQLite creates with the database's mode) are 0600 too; existing ones
    with looser modes are tightened."""
    if not database.parent.exists():
        private_dir(database.parent)
    with contextlib.suppress(FileExistsError):
        os.close(os.open(database, os.O_WRONLY | os.O_CREAT | os.O_EXCL, PRIVATE_FILE))
    for suffix in ("", "-wal", "-shm", "-journal"):
        tighten(database.with_name(database.name + suffix), PRIVATE_FILE)


def prepare_data_dir(root: Path) -> None:
    """The data folder and the coordinator's own folders in it (`sessions/`, `state/`) 0700;
    what an earlier run left there (session folders, their `teleop.json` and logs, the TLS
    folder and key) tightened."""
    private_dir(root)
    sessions = private_dir(root / "sessions")
    private_dir(root / "state")
    for folder in sessions.iterdir():
        if folder.is_dir() and not folder.is_symlink():
            tighten(folder, PRIVATE_DIR)
            for name in ("teleop.json", "teleop.log"):
                tighten(folder / name, PRIVATE_FILE)
    if (root / "tls").is_dir():
        tighten(root / "tls", PRIVATE_DIR)
        tighten(root / "tls" / "key.pem", PRIVATE_FILE)
