"""Per-session telemetry: loop rate and jitter, video, RTT, latency the clients measured."""

from __future__ import annotations

import itertools
import statistics
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any

from crowdteleop.teleop.clock import LoopStats
from crowdteleop.teleop.peering import LinkStats


def percentile(values: list[float], q: float) -> float:
    if not values:
        return 0.0
    ordered = sorted(values)
    index = min(len(ordered) - 1, max(0, round(q / 100 * (len(ordered) - 1))))
    return ordered[index]


def mean_change(values: list[float]) -> float:
    """Mean absolute change between successive samples: RFC 3550's idea of jitter."""
    if len(values) < 2:
        return 0.0
    return statistics.fmean(abs(b - a) for a, b in itertools.pairwise(values))


@dataclass
class SessionTelemetry:
    """Rolling figures a session reports every second and stores with each episode."""

    rtt_ms: deque[float] = field(default_factory=lambda: deque(maxlen=200))
    latency_ms: deque[float] = field(default_factory=lambda: deque(maxlen=2000))
    client_fps: deque[float] = field(default_factory=lambda: deque(maxlen=50))
    receiver_kbps: deque[float] = field(default_factory=lambda: deque(maxlen=50))
    errors: Counter[str] = field(default_factory=Counter)
    frames_published: int = 0
    video_stalls: int = 0  # times the worker's page saw its video stop (clutch released)
    bitrate_kbps: float = 0.0
    _fps_mark: tuple[float, int] = field(default_factory=lambda: (time.monotonic(), 0))
    _bytes_mark: tuple[int, float] = field(default_factory=lambda: (0, time.monotonic()))
    fps: float = 0.0
    loss_fraction: float = 0.0
    rtcp_rtt_ms: float = 0.0
    _episode_mark: tuple[int, int] = (0, 0)  # (episode number, video stalls when it began)

    def episode_running(self, number: int) -> None:
        """Called each tick an episode records: its video stalls count from its first."""
        if number != self._episode_mark[0]:
            self._episode_mark = (number, self.video_stalls)

    def frame_published(self) -> None:
        self.frames_published += 1

    def update_fps(self) -> None:
        now = time.monotonic()
        then, count = self._fps_mark
        if now - then >= 0.5:
            self.fps = (self.frames_published - count) / (now - then)
            self._fps_mark = (now, self.frames_published)

    def update_link(self, link: LinkStats) -> None:
        """The video's rate since the last call, and the loss and round trip the receivers'
        RTCP reports measured (what labels an episode's network condition)."""
        self.update_bitrate(link.bytes_sent)
        if link.packets_sent > 0:
            self.loss_fraction = min(1.0, link.packets_lost / link.packets_sent)
        self.rtcp_rtt_ms = link.rtcp_rtt_s * 1e3
        if link.receiver_estimate_kbps is not None:
            self.receiver_kbps.append(link.receiver_estimate_kbps)

    def update_bitrate(self, total_bytes_sent: int) -> None:
        """The video senders' rate since the last call, from their running byte count."""
        previous, then = self._bytes_mark
        now = time.monotonic()
        if now > then and total_bytes_sent >= previous:
            self.bitrate_kbps = (total_bytes_sent - previous) * 8 / 1000 / (now - then)
        self._bytes_mark = (total_bytes_sent, now)

    def snapshot(self, loop: LoopStats, peer_errors: Counter[str]) -> dict[str, Any]:
        errors = self.errors + peer_errors
        latency = list(self.latency_ms)
        rtt = list(self.rtt_ms)
        return {
            "loop_hz": round(loop.rate_hz(), 2),
            "jitter_ms": round(loop.jitter_ms(), 3),
            "ticks": loop.ticks,
            "overruns": loop.overruns,
            "skipped": loop.skipped,
            "late": loop.late,
            "frames_sent": self.frames_published,
            "video_stalls": self.video_stalls,
            "episode_video_stalls": self.video_stalls - self._episode_mark[1],  # the last's
            "fps": round(self.fps, 2),
            "bitrate_kbps": round(self.bitrate_kbps, 1),
            "rtt_ms": round(statistics.median(rtt), 2) if rtt else 0.0,
            "rtt_min_ms": round(min(rtt), 2) if rtt else 0.0,  # the link's own delay
            "rtt_jitter_ms": round(mean_change(rtt), 2),
            "rtcp_rtt_ms": round(self.rtcp_rtt_ms, 2),
            "loss_fraction": round(self.loss_fraction, 4),
            "latency_p50_ms": round(percentile(latency, 50), 1),
            "latency_p95_ms": round(percentile(latency, 95), 1),
            "client_fps": round(statistics.median(self.client_fps), 1) if self.client_fps else 0,
            # omitted when no receiver reported one: capacity is then not judged from the link
            **(
                {"receiver_kbps": round(statistics.median(self.receiver_kbps), 1)}
                if self.receiver_kbps
                else {}
            ),
            "errors": dict(errors),
        }
