"""Control-to-photon latency (crowdteleop.client.latency): frames matched to the commands they
show, each command timed once."""

from __future__ import annotations

import pytest

from crowdteleop.client.latency import FrameMatcher, LatencyTracker


def test_frames_are_matched_to_commands_despite_an_unknown_rtp_offset():
    matcher = FrameMatcher()
    pts_values = [0, 4493, 9012, 13467, 18020, 22475]
    for seq, pts in enumerate(pts_values, start=10):
        matcher.add_tag(pts, seq)
    offset = 123_456_789
    seen = [matcher.command_seq_of(pts + offset) for pts in pts_values]
    assert seen[:2] == [None, None], "two frames cannot fix the offset"
    assert seen[2:] == [12, 13, 14, 15]


def test_latency_counts_each_command_once_from_its_first_frame():
    tracker = LatencyTracker()
    for seq in (1, 2, 3):
        tracker.command_sent(seq, 10.0 + seq * 0.01)
    assert tracker.frame_shown(2, 10.10) == pytest.approx([90.0, 80.0])
    assert tracker.frame_shown(2, 10.20) == []
    assert tracker.frame_shown(3, 10.25) == pytest.approx([220.0])
