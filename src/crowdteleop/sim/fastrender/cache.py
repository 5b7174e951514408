"""Where derived render assets live: a per-user cache keyed by content, never by path.

Simplifying the robot's meshes takes seconds per arm, rendering from them takes microseconds, so
the results are kept on disk and shared by every process of the user. Entries are named by a hash
of everything that determines them (source bytes and parameters): a changed source file or a new
parameter set simply misses the cache, and nothing ever needs invalidating.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

CACHE_ENV = "CROWDTELEOP_CACHE_DIR"


def cache_root() -> Path:
    """``$CROWDTELEOP_CACHE_DIR``, else ``$XDG_CACHE_HOME/crowdteleop``, else ``~/.cache/...``."""
    explicit = os.environ.get(CACHE_ENV)
    if explicit:
        return Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / "crowdteleop"


def cache_dir(kind: str) -> Path:
    """A sub-directory of the cache root (created on demand)."""
    path = cache_root() / kind
    path.mkdir(parents=True, exist_ok=True)
    return path


def content_key(path: Path, *params: object) -> str:
    """Hash of a file's bytes and the parameters that turn it into a cache entry."""
    digest = hashlib.sha256(path.read_bytes())
    digest.update(repr(params).encode())
    return digest.hexdigest()[:32]


def write_atomically(path: Path, text: str) -> None:
    """Write via a temporary file and rename, so a concurrent reader never sees half a file.

    Two processes building the same entry at once both succeed; the last rename wins and both
    wrote identical content.
    """
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as handle:
            handle.write(text)
        os.chmod(tmp, 0o644)  # mkstemp makes it private; the cache holds nothing secret
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
