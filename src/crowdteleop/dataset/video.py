"""MP4 files from rendered frames (H.264 through PyAV's bundled libx264)."""

from __future__ import annotations

from pathlib import Path
from types import TracebackType

import av
import numpy as np
import numpy.typing as npt


class Mp4Writer:
    """`with Mp4Writer(path, fps) as video: video.write(frame)`; frames are uint8 HxWx3 RGB."""

    def __init__(self, path: str | Path, fps: int, crf: int = 23) -> None:
        self.path = Path(path)
        self.fps = fps
        self.crf = crf
        self.frames_written = 0
        self._container: av.container.OutputContainer | None = None
        self._stream: av.video.stream.VideoStream | None = None

    def __enter__(self) -> Mp4Writer:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._container = av.open(str(self.path), mode="w")
        return self

    def write(self, frame: npt.NDArray[np.uint8]) -> None:
        assert self._container is not None, "use Mp4Writer as a context manager"
        if self._stream is None:
            height, width = frame.shape[:2]
            if width % 2 or height % 2:
                raise ValueError(f"H.264 needs even frame sizes, got {width}x{height}")
            self._stream = self._container.add_stream("libx264", rate=self.fps)
            self._stream.width, self._stream.height = width, height
            self._stream.pix_fmt = "yuv420p"
            self._stream.options = {"crf": str(self.crf), "preset": "veryfast"}
        video_frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")
        for packet in self._stream.encode(video_frame):
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
