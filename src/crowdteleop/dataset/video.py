"""MP4 files from rendered frames, through PyAV's bundled encoders, and MP4 clips joined
without re-encoding into size-limited files (LeRobot keeps episodes back to back in one)."""

from __future__ import annotations

import io
import os
from collections.abc import Callable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import Any, BinaryIO

import av
import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class VideoEncoding:
    """Encoder settings. ``gop`` is the keyframe interval: a decoder seeking to a frame decodes
    from the keyframe before it, so datasets read at random want a small one."""

    codec: str = "libx264"
    crf: int = 23
    gop: int | None = None  # None: the encoder's default (x264: 250)
    preset: str | None = "veryfast"
    pix_fmt: str = "yuv420p"

    def options(self) -> dict[str, str]:
        options = {"crf": str(self.crf)}
        if self.gop is not None:
            options["g"] = str(self.gop)
        if self.preset is not None:
            options["preset"] = self.preset
        return options


PREVIEW = VideoEncoding()
"""Replays to watch: H.264 for every player, x264's default keyframe interval."""
LEROBOT_AV1 = VideoEncoding("libsvtav1", crf=30, gop=2, preset="12")
"""What LeRobot 0.4's ``encode_video_frames`` writes by default (g=2, crf=30, yuv420p)."""
LEROBOT_H264 = VideoEncoding("libx264", crf=30, gop=2, preset=None)
"""LeRobot's ``vcodec="h264"``: the same settings through libx264."""


class Mp4Writer:
    """`with Mp4Writer(path, fps) as video: video.write(frame)`; frames are uint8 HxWx3 RGB.
    ``path`` may be a seekable binary file (an MP4 is finished by seeking back)."""

    def __init__(
        self, path: str | Path | BinaryIO, fps: int, encoding: VideoEncoding = PREVIEW
    ) -> None:
        self.path: Path | BinaryIO = Path(path) if isinstance(path, str | Path) else path
        self.fps = fps
        self.encoding = encoding
        self.frames_written = 0
        self._container: av.container.OutputContainer | None = None
        self._stream: av.video.stream.VideoStream | None = None

    def __enter__(self) -> Mp4Writer:
        if self.encoding.codec == "libsvtav1":
            # SVT-AV1 prints ~20 lines of banner per encoder to stderr unless told errors only.
            os.environ.setdefault("SVT_LOG", "1")
        if isinstance(self.path, Path):
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._container = av.open(str(self.path), mode="w")
        else:
            self._container = av.open(self.path, mode="w", format="mp4")
        return self

    def write(self, frame: npt.NDArray[np.uint8]) -> None:
        assert self._container is not None, "use Mp4Writer as a context manager"
        stream = self._stream
        if stream is None:
            height, width = frame.shape[:2]
            if width % 2 or height % 2:
                raise ValueError(
                    f"{self.encoding.pix_fmt} needs even frame sizes, got {width}x{height}"
                )
            added = self._container.add_stream(
                self.encoding.codec, rate=self.fps, options=self.encoding.options()
            )
            assert isinstance(added, av.video.stream.VideoStream)
            stream = added
            stream.width, stream.height = width, height
            stream.pix_fmt = self.encoding.pix_fmt
            self._stream = stream
        video_frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
        for packet in stream.encode(video_frame):
            self._container.mux(packet)
        self.frames_written += 1

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        assert self._container is not None
        try:
            if self._stream is not None:
                for packet in self._stream.encode(None):
                    self._container.mux(packet)
        finally:
            self._container.close()


def encode_clip(
    frames: npt.NDArray[np.uint8], fps: int, encoding: VideoEncoding = PREVIEW
) -> bytes:
    """One MP4 in memory: its exact size is known before it is placed in a file."""
    buffer = io.BytesIO()
    with Mp4Writer(buffer, fps, encoding) as video:
        for frame in frames:
            video.write(frame)
    return buffer.getvalue()


@dataclass(frozen=True)
class Placed:
    """Where ``Mp4Files.append`` put a clip: which file, from when to when (s) in it."""

    file: int
    start_s: float
    end_s: float


class Mp4Files:
    """`with Mp4Files(path_of, max_bytes) as files: placed = files.append(clip)`: MP4 clips of one
    codec, size and rate back to back in files ``path_of(0)``, ``path_of(1)``, ...; the next file
    starts where the next clip would take this one past ``max_bytes`` (a bigger clip gets a file
    alone). Packets are copied, not re-encoded, each clip shifted to start where the previous
    one ended. A file's clips add up to at least its size (one MP4 header per file)."""

    def __init__(self, path_of: Callable[[int], Path], max_bytes: float) -> None:
        self.path_of, self.max_bytes = path_of, max_bytes
        self.file, self.used = 0, 0  # the current file and the clip bytes in it
        self._end = Fraction(0)  # where the next clip starts in the current file, in seconds
        self._container: av.container.OutputContainer | None = None
        self._stream: av.video.stream.VideoStream | None = None

    def __enter__(self) -> Mp4Files:
        return self

    def append(self, clip: bytes) -> Placed:
        if self._container is not None and self.used + len(clip) > self.max_bytes:
            self.close()
            self.file += 1
        if self._container is None:
            path = self.path_of(self.file)
            path.parent.mkdir(parents=True, exist_ok=True)
            self._container = av.open(str(path), mode="w")
            self._stream, self._end, self.used = None, Fraction(0), 0
        start = end = self._end
        with av.open(io.BytesIO(clip), mode="r") as source:
            stream = source.streams.video[0]
            time_base = stream.time_base
            assert time_base is not None
            if self._stream is None:
                self._stream = self._container.add_stream_from_template(stream, opaque=True)
                self._stream.time_base = time_base
            shift = int(start / time_base)
            for packet in source.demux(stream):
                if packet.dts is None or packet.pts is None:  # the demuxer's flush packet
                    continue
                end = max(end, start + (packet.pts + (packet.duration or 0)) * time_base)
                packet.pts += shift
                packet.dts += shift
                packet.stream = self._stream
                self._container.mux(packet)
        self._end = end
        self.used += len(clip)
        return Placed(self.file, float(start), float(end))

    def close(self) -> None:
        """Finishes the current file (the next ``append`` starts another)."""
        if self._container is not None:
            self._container.close()
            self._container = None

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


def video_info(path: Path) -> dict[str, Any]:
    """The first video stream of ``path`` described as LeRobot's ``get_video_info`` does (the
    ``info`` of a video feature in its ``meta/info.json``)."""
    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        return {
            "video.height": stream.height,
            "video.width": stream.width,
            "video.codec": stream.codec_context.codec.canonical_name,
            "video.pix_fmt": stream.pix_fmt,
            "video.is_depth_map": False,
            "video.fps": int(stream.base_rate or 0),
            "video.channels": 3,
            "has_audio": len(container.streams.audio) > 0,
        }
