"""What the dataset tools say of one episode: its interface, network condition and region, as
read from its metadata and telemetry (`DemoSummary`), for stats and filter keys."""

from __future__ import annotations

from collections import Counter
from typing import Any

from crowdteleop.dataset.files import NO_REGION, DemoSummary
from crowdteleop.recording.episode_file import Episode
from crowdteleop.recording.metadata import EpisodeMetadata

# The paper's conditions (Sec. 4.3): 2.4 Mbps vs 500 kbps, 20 ms vs 120 ms one way.
LOW_CAPACITY_KBPS = 1000.0
HIGH_DELAY_RTT_MS = 150.0
LOSSY_FRACTION = 0.02
QUEUE_MS = 50.0  # median minus minimum round trip: a bottleneck's queue
CONGESTED_LOSS = 0.005


def interface_of(episode: Episode) -> str:
    """The interface the worker used: as recorded, else the devices that sent commands."""
    named = EpisodeMetadata.model_validate(episode.metadata).interface
    if named:
        return named
    devices = Counter(device for c in episode.commands if (device := c.get("device")))
    return devices.most_common(1)[0][0] if devices else "unknown"


def network_of(metadata: dict[str, Any]) -> str:
    """The network condition: a label the campaign set, else one read off what was measured on
    the link (the paper's four: baseline, low-capacity, high-delay, both; "+lossy" past 2 %
    loss), else "unknown".

    Delay is the link's own: the smallest data-channel round trip of the episode (a queue adds
    to the median, not to the minimum). Capacity is low when the receiver's bandwidth estimate
    (its REMB, ``receiver_kbps``) is under 1 Mbps *and* the link shows it is the bottleneck: a
    queue (median round trip 50 ms above the minimum) or loss. An estimate alone says little:
    receivers ramp it up from what arrives, and aiortc starts every stream at 500 kbps, on
    loopback too; the encoder's own rate is never used."""
    named = metadata.get("network_condition")
    if isinstance(named, str) and named:
        return named
    telemetry = metadata.get("telemetry") or {}
    rtt = telemetry.get("rtt_ms") or telemetry.get("rtcp_rtt_ms")
    base_rtt = telemetry.get("rtt_min_ms") or rtt
    estimate = telemetry.get("receiver_kbps")
    if not rtt and not estimate:
        return "unknown"
    loss = telemetry.get("loss_fraction") or 0.0
    queued = bool(rtt and base_rtt and rtt - base_rtt >= QUEUE_MS)
    slow = bool(estimate and estimate < LOW_CAPACITY_KBPS and (queued or loss >= CONGESTED_LOSS))
    late = bool(base_rtt and base_rtt >= HIGH_DELAY_RTT_MS)
    label = {
        (False, False): "baseline",
        (True, False): "low-capacity",
        (False, True): "high-delay",
        (True, True): "both",
    }[(slow, late)]
    return f"{label}+lossy" if loss >= LOSSY_FRACTION else label


def summarize(name: str, episode: Episode, drift: float | None = None) -> DemoSummary:
    info = EpisodeMetadata.model_validate(episode.metadata)
    return DemoSummary(
        name=name,
        episode_id=episode.episode_id,
        task=info.task,
        outcome=episode.outcome,
        interface=interface_of(episode),
        worker=info.worker_id or "unknown",
        network=network_of(episode.metadata),
        region=region_of(episode.metadata),
        campaign=str(episode.metadata.get("campaign") or ""),
        steps=episode.steps,
        completion_s=episode.steps / info.control_hz,
        drift=drift,
    )


def region_of(metadata: dict[str, Any]) -> str:
    """The region whose teleop server recorded the episode (a campaign with regions)."""
    region = EpisodeMetadata.model_validate(metadata).region
    return region.region if region is not None else NO_REGION
