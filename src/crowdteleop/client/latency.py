"""Control-to-photon latency: which command each decoded frame shows, and since when.

The server tags every frame it publishes with its RTP-clock ``pts`` and the last command the
frame reflects (a ``frame`` message on the events channel). A receiver sees the RTP timestamp
plus an offset it cannot know (the sender adds a random origin; aiortc's receiver rebases to
its first packet). Frame times come from the wall clock, so the gaps between them are
irregular: the one offset under which two decoded frames both land on tagged pts is the
right one.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from dataclasses import dataclass, field

MAX_TAGS = 600  # 30 s of frames at 20 fps
RTP_MODULO = 2**32
CANDIDATES = 60  # a decoded frame is one of the last few seconds' frames


@dataclass
class FrameMatcher:
    tags: OrderedDict[int, int] = field(default_factory=OrderedDict)  # pts -> command seq
    offset: int | None = None
    _recent: deque[int] = field(default_factory=lambda: deque(maxlen=8))

    def add_tag(self, pts: int, command_seq: int) -> None:
        self.tags[pts] = command_seq
        while len(self.tags) > MAX_TAGS:
            self.tags.popitem(last=False)

    def command_seq_of(self, rtp_timestamp: int) -> int | None:
        """The command a decoded frame reflects, or None while the offset is unknown."""
        if self.offset is not None:
            pts = (rtp_timestamp - self.offset) % RTP_MODULO
            if pts in self.tags:
                return self.tags[pts]
        self._recent.append(rtp_timestamp)
        offset = self._find_offset()
        if offset is None:
            return None
        self.offset = offset
        return self.tags.get((rtp_timestamp - offset) % RTP_MODULO)

    def _find_offset(self) -> int | None:
        """Three frames must agree: with frame gaps jittering by tens of RTP ticks, a wrong
        offset that lands two earlier frames on tags by chance is vanishingly rare."""
        if len(self._recent) < 3:
            return None
        newest, earlier = self._recent[-1], list(self._recent)[:-1]
        for pts in list(reversed(self.tags))[:CANDIDATES]:
            offset = (newest - pts) % RTP_MODULO
            if sum((r - offset) % RTP_MODULO in self.tags for r in earlier) >= 2:
                return offset
        return None


@dataclass
class LatencyTracker:
    """Send times by command seq; each command's latency is the first frame showing it."""

    sent: OrderedDict[int, float] = field(default_factory=OrderedDict)
    samples_ms: list[float] = field(default_factory=list)
    _shown_up_to: int = -1

    def command_sent(self, seq: int, when: float) -> None:
        self.sent[seq] = when
        while len(self.sent) > 2000:
            self.sent.popitem(last=False)

    def frame_shown(self, command_seq: int, when: float) -> list[float]:
        new: list[float] = []
        if command_seq <= self._shown_up_to:
            return new
        for seq in [s for s in self.sent if self._shown_up_to < s <= command_seq]:
            new.append((when - self.sent.pop(seq)) * 1e3)
        self._shown_up_to = command_seq
        self.samples_ms.extend(new)
        return new
