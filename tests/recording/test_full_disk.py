"""A recorder on a really full disk (a small tmpfs): finalizing fails cleanly, wherever in the
file the space runs out, and succeeds once there is space again."""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from crowdteleop.recording.episode_file import read_episode
from crowdteleop.recording.storage import disk_is_full
from crowdteleop.recording.wal import EpisodeRecorder
from crowdteleop.recording.wal_reader import read_partial
from crowdteleop.recording.wal_recovery import recover_orphans
from tests.fixtures import recording_child as child

METADATA = {
    "task": "lift",
    "session_id": "s-1",
    "model_xml": "<mujoco model='lift'>" + "<body/>" * 20000 + "</mujoco>",  # ~140 kB
    "env_args": {"env_name": "Lift", "env_kwargs": {"robots": ["Sawyer"]}},
}
STEPS = 40


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root (CI runs as root)")
    disk = tmp_path / "disk"
    disk.mkdir()
    subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(disk)], check=True)
    try:
        yield disk
    finally:
        subprocess.run(["umount", "-l", str(disk)], check=False)


def _leave_free(disk: Path, free_bytes: int) -> Path:
    """Fill the disk until about `free_bytes` are left."""
    stats = os.statvfs(disk)
    filler = disk / "filler"
    with open(filler, "wb") as file:
        file.write(b"\0" * max(0, stats.f_bavail * stats.f_frsize - free_bytes))
    return filler


@pytest.mark.parametrize("free_kb", [0, 8, 40, 100, 140])
def test_finalizing_on_a_full_disk_fails_cleanly_and_succeeds_with_space_again(
    small_disk: Path, free_kb: int
) -> None:
    recorder = EpisodeRecorder(small_disk, "ep-1", METADATA, flush_interval_s=0.0)
    for index in range(STEPS):
        recorder.append(child.make_step(index))
    filler = _leave_free(small_disk, free_kb * 1024)

    with pytest.raises(OSError) as failure:
        recorder.finalize("success")
    assert disk_is_full(failure.value), failure.value
    assert sorted(p.name for p in small_disk.iterdir()) == ["ep-1.wal", "filler"], "no half file"
    assert read_partial(recorder.wal_path).steps == STEPS
    assert recover_orphans(small_disk) == [], "a live recorder's log is left alone"

    filler.unlink()
    episode = read_episode(recorder.finalize("success"))
    assert episode.outcome == "success" and episode.steps == STEPS


def test_recovery_on_a_full_disk_keeps_the_log_for_the_next_try(small_disk: Path) -> None:
    recorder = EpisodeRecorder(small_disk, "ep-1", METADATA, flush_interval_s=0.0)
    for index in range(STEPS):
        recorder.append(child.make_step(index))
    recorder.close()  # as a crashed server leaves it
    filler = _leave_free(small_disk, 16 * 1024)

    assert recover_orphans(small_disk) == []
    assert read_partial(small_disk / "ep-1.wal").steps == STEPS

    filler.unlink()
    [path] = recover_orphans(small_disk)
    episode = read_episode(path)
    assert episode.outcome == "crash" and episode.recovered and episode.steps == STEPS
