"""An episode as a video for the reviewer (docs/review.md): rendered from its recorded states
by the replay tool (`crowdteleop dataset replay`) in a subprocess, so the coordinator loads no
simulator; cached under the data directory, one render per episode at a time; the first
frame kept as a JPEG for the grid's thumbnail.

An s3:// episode is downloaded into the cache first. A render that fails or runs past
`RENDER_TIMEOUT_S` is a `RenderError` naming why, never a hang.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import hmac
import os
import sys
import time
from pathlib import Path

from crowdteleop.coord.db.tables import Episode
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.review import local_path, s3_key, storage_config
from crowdteleop.recording.s3 import S3Storage

RENDER_TIMEOUT_S = 300.0
WIDTH, HEIGHT = 320, 240
THUMBNAILS_AT_ONCE = 1  # background renders for thumbnails; a video asked for waits for none
LINK_LIFETIME_S = 3600.0
RETRY_AFTER_S = 60.0  # a failed render is told again, not retried, for this long


class RenderError(Exception):
    """The episode could not be rendered: the message says why."""


class MediaLinks:
    """Signed links to an episode's video and thumbnail: a <video> or <img> cannot send the
    reviewer's bearer token, so the episode's view carries links valid for an hour, signed
    with a key derived from the admin token (the same on every replica)."""

    def __init__(self, admin_token: str) -> None:
        self._key = hmac.new(admin_token.encode(), b"crowdteleop review media", "sha256").digest()

    def query(self, episode_id: str, now: float | None = None) -> str:
        expires = int((now or time.time()) + LINK_LIFETIME_S)
        return f"expires={expires}&sig={self._sign(episode_id, expires)}"

    def valid(self, episode_id: str, expires: int, sig: str) -> bool:
        return expires >= time.time() and hmac.compare_digest(sig, self._sign(episode_id, expires))

    def _sign(self, episode_id: str, expires: int) -> str:
        message = f"{episode_id}:{expires}".encode()
        return hmac.new(self._key, message, hashlib.sha256).hexdigest()[:32]


class EpisodeVideos:
    """Rendered videos and thumbnails, cached in `<data_dir>/review/videos`."""

    def __init__(self, config: CoordConfig) -> None:
        self.cache = config.data_dir / "review" / "videos"
        self._storage = storage_config(config)
        self._locks: dict[str, tuple[asyncio.Lock, int]] = {}  # id -> (lock, coroutines using it)
        self._failed: dict[str, tuple[float, str]] = {}  # id -> (when, why): not retried at once
        self._thumbnails = asyncio.Semaphore(THUMBNAILS_AT_ONCE)

    async def video(self, episode: Episode) -> Path:
        """The episode's MP4, rendered once."""
        target = self.cache / f"{episode.episode_id}.mp4"
        self._raise_recent_failure(episode.episode_id)
        lock, users = self._locks.get(episode.episode_id, (asyncio.Lock(), 0))
        self._locks[episode.episode_id] = (lock, users + 1)
        try:
            async with lock:
                if not target.is_file():
                    self._raise_recent_failure(episode.episode_id)  # while this one waited
                    await self._render(episode, target)
        finally:
            lock, users = self._locks[episode.episode_id]
            if users == 1:  # the last one asking: forget the lock
                del self._locks[episode.episode_id]
            else:
                self._locks[episode.episode_id] = (lock, users - 1)
        return target

    def _raise_recent_failure(self, episode_id: str) -> None:
        failed = self._failed.get(episode_id)
        if failed is not None and time.monotonic() - failed[0] < RETRY_AFTER_S:
            raise RenderError(failed[1])

    async def thumbnail(self, episode: Episode) -> Path:
        """The first frame as a JPEG, the video rendered first if needed (one thumbnail
        render at a time, so a grid does not start a render per card at once)."""
        target = self.cache / f"{episode.episode_id}.jpg"
        if target.is_file():
            return target
        async with self._thumbnails:
            video = await self.video(episode)
        if not target.is_file():
            await asyncio.to_thread(first_frame, video, target)
        return target

    async def _render(self, episode: Episode, target: Path) -> None:
        try:
            await self._render_once(episode, target)
        except RenderError as error:
            self._failed[episode.episode_id] = (time.monotonic(), str(error))
            raise

    async def _render_once(self, episode: Episode, target: Path) -> None:
        self.cache.mkdir(parents=True, exist_ok=True)
        source = local_path(episode.uri)
        downloaded = None
        if source is None:
            source = downloaded = self.cache / f"{episode.episode_id}.hdf5"
            await asyncio.to_thread(self._download, episode.uri, downloaded)
        elif not source.is_file():
            raise RenderError(f"the episode file {source} is missing")
        partial = target.with_name(f".{target.stem}.partial.mp4")
        try:
            await replay(source, partial)
            os.replace(partial, target)
        finally:
            partial.unlink(missing_ok=True)
            if downloaded is not None:
                downloaded.unlink(missing_ok=True)

    def _download(self, uri: str, local: Path) -> None:
        s3 = self._storage.s3
        if s3 is None or not uri.startswith("s3://"):
            raise RenderError(f"cannot read {uri}: not a local file or in the configured S3 store")
        try:
            s3_key(uri, s3)
            S3Storage(s3).get(uri, local)
        except Exception as error:
            raise RenderError(f"cannot download {uri}: {error}") from error


async def replay(source: Path, output: Path) -> None:
    """`crowdteleop dataset replay` of `source` into `output`, in a subprocess."""
    command = [sys.executable, "-m", "crowdteleop", "dataset", "replay", str(source)]
    command += ["--output", str(output), "--width", str(WIDTH), "--height", str(HEIGHT)]
    process = await asyncio.create_subprocess_exec(
        *command, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT
    )
    try:
        out, _ = await asyncio.wait_for(process.communicate(), RENDER_TIMEOUT_S)
    except TimeoutError:
        with contextlib.suppress(ProcessLookupError):
            process.kill()
        await process.wait()
        raise RenderError(f"rendering took longer than {RENDER_TIMEOUT_S:.0f} s") from None
    except asyncio.CancelledError:
        with contextlib.suppress(ProcessLookupError):
            process.kill()
        raise
    if process.returncode != 0 or not output.is_file():
        lines = out.decode(errors="replace").strip().splitlines()[-3:]
        raise RenderError(f"the replay tool failed ({process.returncode}): {' / '.join(lines)}")


def first_frame(video: Path, target: Path) -> None:
    """The video's first frame as a JPEG at `target` (blocking: call in a thread)."""
    import av  # PyAV, which aiortc brings; imported only here

    partial = target.with_name(f".{target.name}.partial")
    with av.open(str(video)) as source:
        frame = next(source.decode(video=0))
    with av.open(str(partial), "w", format="image2") as out:
        stream = out.add_stream("mjpeg")
        stream.width, stream.height, stream.pix_fmt = frame.width, frame.height, "yuvj420p"
        for packet in stream.encode(frame.reformat(format="yuvj420p")):
            out.mux(packet)
        for packet in stream.encode(None):
            out.mux(packet)
    os.replace(partial, target)
