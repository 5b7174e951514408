"""The receiver's bandwidth estimate (REMB) for a video sender, as the receiver sent it.

Browsers estimate the bandwidth the video may use and send it back in RTCP REMB packets;
aiortc hands it only to its encoder, which clamps it to its own range (VP8 250 kbps - 1.5 Mbps)
and exposes neither. What labels an episode's network condition must be the link's figure, not
the encoder's choice, so each video sender's RTCP handler is tapped on the instance (aiortc
dispatches RTCP through ``recipient._handle_rtcp_packet``) to keep the last estimate.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any

from aiortc import RTCRtpSender
from aiortc.rtp import RTCP_PSFB_APP, RtcpPsfbPacket, unpack_remb_fci


class RembTap:
    """The last receiver estimate (bits/s) seen by one sender; None until one arrives."""

    def __init__(self, sender: RTCRtpSender) -> None:
        self.estimate_bps: int | None = None
        handle: Callable[[Any], Awaitable[None]] = sender._handle_rtcp_packet

        async def tapped(packet: Any) -> None:
            if isinstance(packet, RtcpPsfbPacket) and packet.fmt == RTCP_PSFB_APP:
                try:
                    bitrate, _ = unpack_remb_fci(packet.fci)
                except ValueError:
                    pass  # not a REMB packet: aiortc ignores it too
                else:
                    self.estimate_bps = bitrate
            await handle(packet)

        sender._handle_rtcp_packet = tapped  # type: ignore[method-assign]
