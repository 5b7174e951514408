"""The latency matcher against the shared test vectors in tests/fixtures/latency_vectors.json.

The browser's copy (web/static/latency.js) runs the same file in tests/web/latency.test.mjs, so
the Python client and the page cannot disagree on which command a frame shows.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from crowdteleop.client.latency import FrameMatcher, LatencyTracker

VECTORS: dict[str, Any] = json.loads(
    (Path(__file__).resolve().parents[1] / "fixtures" / "latency_vectors.json").read_text()
)


def _name(case: dict[str, Any]) -> str:
    return case["name"]


@pytest.mark.parametrize("case", VECTORS["matcher"], ids=_name)
def test_frame_matcher_finds_the_command_each_frame_shows(case: dict[str, Any]) -> None:
    matcher = FrameMatcher()
    found, expected = [], []
    for step in case["steps"]:
        if "tag" in step:
            matcher.add_tag(*step["tag"])
        elif "tags" in step:
            for pts, seq in step["tags"]:
                matcher.add_tag(pts, seq)
        else:
            found.append(matcher.command_seq_of(step["frame"]))
            expected.append(step["seq"])
    assert found == expected


@pytest.mark.parametrize("case", VECTORS["tracker"], ids=_name)
def test_latency_tracker_times_each_command_to_its_first_frame(case: dict[str, Any]) -> None:
    tracker = LatencyTracker()
    every: list[float] = []
    for step in case["steps"]:
        when_s = step["at_ms"] / 1e3  # the Python tracker takes seconds, reports milliseconds
        if "sent" in step:
            tracker.command_sent(step["sent"], when_s)
        else:
            samples = tracker.frame_shown(step["shown"], when_s)
            assert samples == pytest.approx(step["samples_ms"], abs=1e-6)
            every += step["samples_ms"]
    assert tracker.samples_ms == pytest.approx(every, abs=1e-6)


def test_the_vectors_cover_what_matters() -> None:
    """Guard against a regenerated file that lost its hard cases."""
    names = {case["name"] for case in VECTORS["matcher"]}
    assert {"wraparound", "offset_changes", "late_tags", "evicted_tags"} <= names
    frames = [s for case in VECTORS["matcher"] for s in case["steps"] if "frame" in s]
    assert any(s["seq"] is None for s in frames) and sum(s["seq"] is not None for s in frames) > 200
