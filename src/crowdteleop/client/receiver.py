"""A video receiver that hands a frame to the decoder as soon as its last packet arrives.

aiortc's jitter buffer declares a frame complete only when a packet of the *next* frame
arrives, which delays every frame by one frame interval (50 ms at 20 fps). Browsers complete a
frame on the RTP marker bit, which the sender sets on a frame's last packet. The client uses
the browser's rule, so what it measures is what a worker's browser sees.
"""

from __future__ import annotations

import aiortc.rtcrtpreceiver
from aiortc.jitterbuffer import JitterBuffer, JitterFrame
from aiortc.rtp import RtpPacket


class MarkerJitterBuffer(JitterBuffer):
    def _remove_frame(self, sequence_number: int) -> JitterFrame | None:
        if not self._is_video or self._origin is None:
            return super()._remove_frame(sequence_number)
        packets: list[RtpPacket] = []
        for count in range(self.capacity):
            packet = self._packets[(self._origin + count) % self.capacity]
            if packet is None:
                return None
            if packets and packet.timestamp != packets[0].timestamp:
                return super()._remove_frame(sequence_number)  # no marker seen: aiortc's rule
            packets.append(packet)
            if packet.marker:
                # aiortc's receiver stores each packet's depayloaded bytes in `_data` at runtime
                data = b"".join(p._data for p in packets)  # type: ignore[attr-defined]
                frame = JitterFrame(data=data, timestamp=packet.timestamp)
                self.remove(count + 1)
                return frame
        return None


def complete_frames_on_marker() -> None:
    """Use `MarkerJitterBuffer` for the receivers this process creates from now on."""
    # The receiver module imports JitterBuffer without re-exporting it; replace that name.
    aiortc.rtcrtpreceiver.JitterBuffer = MarkerJitterBuffer  # type: ignore[attr-defined]
