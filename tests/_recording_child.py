"""The process the crash test kills: records steps until killed, printing each flush.

    python tests/_recording_child.py DIRECTORY EPISODE_ID

Prints ``flushed N`` (stdout, line-buffered) each time ``flushed_steps`` grows, i.e. after the
fsync returned: a promise that the first N steps survive a ``kill -9``.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from crowdteleop.recording.episode_file import StepRecord
from crowdteleop.recording.wal import EpisodeRecorder

STATE_SIZE = 71
ACTION_SIZE = 8
FLUSH_INTERVAL_S = 0.2
METADATA = {"task": "lift", "robot": "Sawyer", "model_xml": "<mujoco model='crash'/>"}


def make_step(index: int) -> StepRecord:
    """Step ``index`` of the child's episode, reproducible bit for bit by the test."""
    rng = np.random.default_rng(index)
    state = rng.standard_normal(STATE_SIZE) * 10.0 ** rng.integers(-300, 300, STATE_SIZE)
    state[:3] = [index * 0.05, -0.0, 5e-324]  # time, a negative zero, a subnormal
    return StepRecord(
        index=index,
        state=state,
        action=rng.uniform(-1, 1, ACTION_SIZE),
        command={
            "seq": index,
            "client_time_ms": 1000.0 + index / 20,
            "engaged": True,
            "device": "phone",
        },
        server_time=2000.0 + index / 20,
        step_duration_s=float(rng.uniform(0.001, 0.01)),
        reward=float(index % 2),
        success=False,
        contacts=[{"robot_part": "finger", "object": "cube", "intensity": float(rng.random())}],
    )


def main(directory: Path, episode_id: str) -> None:
    recorder = EpisodeRecorder(directory, episode_id, METADATA, FLUSH_INTERVAL_S)
    print("started", flush=True)
    reported = 0
    index = 0
    while True:
        recorder.append(make_step(index))
        index += 1
        if recorder.flushed_steps != reported:
            reported = recorder.flushed_steps
            print(f"flushed {reported}", flush=True)
        time.sleep(0.005)


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2])
