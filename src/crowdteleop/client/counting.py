"""Receive video without decoding it: for load tests with many clients on one machine.

aiortc decodes every received frame in a thread of the receiver, with no option to skip it.
A load test's extra clients only need to know that frames arrived (and their RTP timestamps),
so this swaps, for the whole client process, the decoder aiortc makes for a tiny frame that
carries the timestamp. Never call it in a server process.
"""

from __future__ import annotations

import aiortc.rtcrtpreceiver
from aiortc.codecs.base import Decoder
from aiortc.jitterbuffer import JitterFrame
from av import VideoFrame
from av.frame import Frame

from crowdteleop.teleop.video import TIME_BASE


class _CountingDecoder(Decoder):
    def decode(self, encoded_frame: JitterFrame) -> list[Frame]:
        frame = VideoFrame(width=2, height=2, format="yuv420p")
        frame.pts = encoded_frame.timestamp
        frame.time_base = TIME_BASE
        return [frame]


def disable_decoding() -> None:
    # The receiver module imports get_decoder without re-exporting it; replace that name.
    aiortc.rtcrtpreceiver.get_decoder = (  # type: ignore[attr-defined]
        lambda codec: _CountingDecoder()
    )
