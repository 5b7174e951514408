"""Episode recording: what is appended comes back bit for bit, from the finished HDF5 file and
from the write-ahead log a killed process leaves; bad input never damages what was recorded."""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import signal
import struct
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

import h5py
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from crowdteleop.errors import InvalidActionError, InvalidStateError
from crowdteleop.recording.episode_file import (
    CorruptEpisodeError,
    InvalidRecordError,
    RecordingError,
    StepRecord,
    read_episode,
)
from crowdteleop.recording.storage import (
    EpisodeStorage,
    InvalidKeyError,
    KeyExistsError,
    LocalDirectoryStorage,
    ObjectNotFoundError,
)
from crowdteleop.recording.wal import EpisodeRecorder
from crowdteleop.recording.wal_reader import read_partial
from crowdteleop.recording.wal_recovery import recover_orphans
from crowdteleop.vocab import OUTCOMES
from tests.fixtures import recording_child as child

METADATA = {
    "task": "lift",
    "robot": "Sawyer",
    "controller": "ik-velocity",
    "session_id": "s-1",
    "worker_id": "w-7",
    "model_xml": "<mujoco model='lift'>" + "<body/>" * 20000 + "</mujoco>",  # ~140 kB
    "env_args": {"env_name": "Lift", "env_kwargs": {"robots": ["Sawyer"]}},
}


def record(directory: Path, steps: int, episode_id: str = "ep-1", **kwargs) -> EpisodeRecorder:
    recorder = EpisodeRecorder(directory, episode_id, METADATA, **kwargs)
    for index in range(steps):
        recorder.append(child.make_step(index))
    return recorder


def bits(array: np.ndarray) -> bytes:
    return np.ascontiguousarray(array, dtype="<f8").tobytes()


def assert_holds_child_steps(episode, steps: int) -> None:
    expected = [child.make_step(i) for i in range(steps)]
    assert episode.steps == steps
    assert bits(episode.states) == bits(np.array([s.state for s in expected]))
    assert bits(episode.actions) == bits(np.array([s.action for s in expected]))
    assert episode.commands == [s.command for s in expected]
    assert episode.contacts == [s.contacts for s in expected]
    assert bits(episode.step_duration_s) == bits(np.array([s.step_duration_s for s in expected]))


def test_round_trip_is_bit_exact_and_robomimic_shaped(tmp_path):
    recorder = record(tmp_path, 30, flush_interval_s=0.0)
    assert (recorder.steps, recorder.flushed_steps) == (30, 30)
    path = recorder.finalize("success", {"telemetry": {"rtt_ms": 12.5}})
    assert path == tmp_path / "ep-1.hdf5"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ep-1.hdf5"]  # the log is gone

    episode = read_episode(path)
    assert_holds_child_steps(episode, 30)
    assert (episode.episode_id, episode.outcome, episode.recovered) == ("ep-1", "success", False)
    assert episode.model_xml == METADATA["model_xml"]
    assert episode.env_args == {"env_name": "Lift", "type": 1, "env_kwargs": {"robots": ["Sawyer"]}}
    assert episode.metadata["worker_id"] == "w-7"
    assert episode.metadata["telemetry"] == {"rtt_ms": 12.5}
    assert "model_xml" not in episode.metadata
    assert episode.dones.tolist() == [0] * 29 + [1]

    with h5py.File(path, "r") as file:
        demo = file["data/demo_0"]
        assert demo["states"].shape == (30, child.STATE_SIZE)
        assert demo["actions"].shape == (30, child.ACTION_SIZE)
        assert demo["rewards"].shape == demo["dones"].shape == (30,)
        assert demo.attrs["num_samples"] == file["data"].attrs["total"] == 30
        assert demo.attrs["model_file"] == METADATA["model_xml"]
        assert json.loads(file["data"].attrs["env_args"])["type"] == 1
        assert file.attrs["outcome"] == "success"
        assert demo["commands/seq"][()].tolist() == list(range(30))
        assert demo["commands/client_time_ms"][3] == 1000.0 + 3 / 20
        assert np.isnan(demo["commands/position"][()]).all()  # the child's commands lack it
        assert json.loads(demo["contacts"].asstr()[0])[0]["object"] == "cube"


def test_appends_are_buffered_until_the_flush_interval(tmp_path):
    recorder = record(tmp_path, 5, flush_interval_s=3600.0)
    assert (recorder.steps, recorder.flushed_steps) == (5, 0)
    assert read_partial(recorder.wal_path).steps == 0  # the header alone is durable
    recorder.flush()
    assert recorder.flushed_steps == 5
    assert_holds_child_steps(read_partial(recorder.wal_path), 5)
    recorder.finalize("reset")


def test_bad_steps_raise_and_leave_the_recording_intact(tmp_path):
    recorder = record(tmp_path, 3, flush_interval_s=0.0)
    good = child.make_step(3)

    def bad(**changes) -> StepRecord:
        return dataclasses.replace(good, **changes)

    nan_state = good.state.copy()
    nan_state[5] = np.nan
    with pytest.raises(InvalidStateError, match="NaN"):
        recorder.append(bad(state=nan_state))
    with pytest.raises(InvalidActionError, match="NaN or infinity"):
        recorder.append(bad(action=np.full(child.ACTION_SIZE, np.inf)))
    with pytest.raises(InvalidStateError, match="earlier steps"):
        recorder.append(bad(state=good.state[:-1]))
    with pytest.raises(InvalidActionError, match="earlier steps"):
        recorder.append(bad(action=np.zeros(child.ACTION_SIZE + 1)))
    with pytest.raises(InvalidStateError, match="flat vector"):
        recorder.append(bad(state=good.state.reshape(1, -1)))
    with pytest.raises(InvalidRecordError, match="out of order"):
        recorder.append(bad(index=7))
    with pytest.raises(InvalidRecordError, match="reward"):
        recorder.append(bad(reward=float("nan")))
    with pytest.raises(InvalidRecordError, match="outcome"):
        recorder.finalize("won")  # type: ignore[arg-type]
    assert (recorder.steps, recorder.flushed_steps) == (3, 3)

    recorder.append(good)
    path = recorder.finalize("timeout")
    assert_holds_child_steps(read_episode(path), 4)
    for call in (lambda: recorder.append(child.make_step(4)), recorder.flush):
        with pytest.raises(RecordingError, match="finalized"):
            call()
    with pytest.raises(RuntimeError):
        recorder.finalize("success")
    assert read_episode(path).outcome == "timeout"


def test_a_command_or_contacts_json_refuses_are_recorded_as_a_counted_note(tmp_path):
    recorder = record(tmp_path, 3, flush_interval_s=0.0)
    good = child.make_step(3)
    recorder.append(dataclasses.replace(good, command={"client_time_ms": float("nan")}))
    recorder.append(dataclasses.replace(child.make_step(4), contacts=[{"object": object()}]))

    assert (recorder.steps, recorder.flushed_steps, recorder.notes) == (5, 5, 2)
    episode = read_episode(recorder.finalize("success"))
    assert episode.states.shape[0] == 5
    np.testing.assert_array_equal(episode.states[3], good.state)  # the step itself is kept
    assert "JSON" in episode.commands[3]["unrecordable"]
    assert "JSON" in episode.contacts[4][0]["unrecordable"]
    assert episode.commands[4] == child.make_step(4).command


def test_a_failed_flush_keeps_the_log_whole_and_retries(tmp_path, monkeypatch):
    recorder = record(tmp_path, 2, flush_interval_s=0.0)
    real_write, wal_inode = os.write, recorder.wal_path.stat().st_ino

    def disk_full_midway(fd, data):
        if os.fstat(fd).st_ino == wal_inode:
            real_write(fd, bytes(data[: len(data) // 2]))
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", disk_full_midway)
    with pytest.raises(RecordingError, match="No space left"):
        recorder.append(child.make_step(2))  # buffered, not durable
    assert (recorder.steps, recorder.flushed_steps) == (3, 2)
    assert read_partial(recorder.wal_path).ignored_tail_bytes == 0  # cut back to whole records
    monkeypatch.undo()
    recorder.append(child.make_step(3))  # the next flush writes both
    assert recorder.flushed_steps == 4
    assert_holds_child_steps(read_episode(recorder.finalize("success")), 4)


def test_bad_episode_ids_and_metadata_are_refused(tmp_path):
    for episode_id in ("", "../escape", "a/b", ".hidden", "x" * 200):
        with pytest.raises(InvalidRecordError, match="episode id"):
            EpisodeRecorder(tmp_path, episode_id, METADATA)
    with pytest.raises(InvalidRecordError, match="JSON"):
        EpisodeRecorder(tmp_path, "ep", {"when": object()})
    with pytest.raises(InvalidRecordError, match="env_name"):
        EpisodeRecorder(tmp_path, "ep", {"env_args": {"env_kwargs": {}}})
    assert list(tmp_path.iterdir()) == []


def test_one_episode_id_records_once(tmp_path):
    recorder = record(tmp_path, 2)
    with pytest.raises(RecordingError, match="already has a write-ahead log"):
        EpisodeRecorder(tmp_path, "ep-1", METADATA)
    path = recorder.finalize("success")
    with pytest.raises(RecordingError, match="already recorded"):
        EpisodeRecorder(tmp_path, "ep-1", METADATA)
    assert_holds_child_steps(read_episode(path), 2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ep-1.hdf5"]


def test_an_empty_episode_finalizes(tmp_path):
    path = EpisodeRecorder(tmp_path, "empty", METADATA).finalize("disconnect")
    episode = read_episode(path)
    assert (episode.steps, episode.outcome) == (0, "disconnect")
    assert episode.states.shape[0] == episode.actions.shape[0] == 0


def test_a_torn_or_damaged_log_tail_is_ignored(tmp_path):
    recorder = record(tmp_path, 2, flush_interval_s=0.0)
    two_steps = recorder.wal_path.stat().st_size
    recorder.append(child.make_step(2))
    log = recorder.wal_path.read_bytes()
    recorder.close()
    copy = tmp_path / "copy.wal"

    for cut in range(two_steps, len(log)):  # every way the last record can be torn
        copy.write_bytes(log[:cut])
        partial = read_partial(copy)
        assert (partial.steps, partial.ignored_tail_bytes) == (2, cut - two_steps)
    assert_holds_child_steps(partial, 2)

    copy.write_bytes(log + bytes(4096))  # the zeros a power loss can leave
    assert (read_partial(copy).steps, read_partial(copy).ignored_tail_bytes) == (3, 4096)
    damaged = bytearray(log)
    damaged[two_steps - 10] ^= 0x01  # one flipped bit in the second step
    copy.write_bytes(bytes(damaged))
    assert read_partial(copy).steps == 1

    copy.write_bytes(log[:20])  # inside the header
    with pytest.raises(CorruptEpisodeError, match="header"):
        read_partial(copy)
    copy.write_bytes(b"PK\x03\x04 not a log")
    with pytest.raises(CorruptEpisodeError, match="not a crowdteleop write-ahead log"):
        read_partial(copy)


def test_recover_orphans_finalizes_abandoned_logs_as_crashes(tmp_path):
    record(tmp_path, 7, "abandoned").close()  # as if the process died after a flush
    live = record(tmp_path, 3, "live", flush_interval_s=0.0)
    (tmp_path / "broken.wal").write_bytes(b"CTWAL01\n\x00\x00")
    (tmp_path / ".gone.wal.123-4.tmp").write_bytes(b"CTWAL01\n")

    assert recover_orphans(tmp_path) == [tmp_path / "abandoned.hdf5"]
    episode = read_episode(tmp_path / "abandoned.hdf5")
    assert (episode.outcome, episode.recovered) == ("crash", True)
    assert_holds_child_steps(episode, 7)
    assert episode.model_xml == METADATA["model_xml"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "abandoned.hdf5",
        "broken.wal.corrupt",
        "live.wal",
    ]
    assert recover_orphans(tmp_path) == []  # the live recorder's log is left alone
    assert_holds_child_steps(read_episode(live.finalize("success")), 3)
    assert recover_orphans(tmp_path / "missing") == []


def test_a_log_that_died_before_its_first_flush_is_removed_not_kept_empty(tmp_path):
    record(tmp_path, 0, "empty").close()  # the header is on disk, no step yet
    assert (tmp_path / "empty.wal").exists()
    assert recover_orphans(tmp_path) == []
    assert list(tmp_path.iterdir()) == [], "no episode without steps for dataset build to trip on"


def test_recover_orphans_after_a_crash_inside_finalize(tmp_path):
    # Killed after the file's rename, before the log's removal: the finished file wins.
    recorder = record(tmp_path, 4, "renamed", flush_interval_s=0.0)
    log = recorder.wal_path.read_bytes()
    path = recorder.finalize("success")
    recorder.wal_path.write_bytes(log)
    # Killed while writing the file: a temporary half file, the log intact.
    record(tmp_path, 5, "half").close()
    (tmp_path / ".half.hdf5.tmp").write_bytes(b"\x89HDF\r\n half")

    assert recover_orphans(tmp_path) == [tmp_path / "half.hdf5", path]
    assert read_episode(path).outcome == "success"
    assert_holds_child_steps(read_episode(tmp_path / "half.hdf5"), 5)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["half.hdf5", "renamed.hdf5"]


def test_foreign_or_truncated_episode_files_raise_clearly(tmp_path):
    foreign = tmp_path / "foreign.hdf5"
    with h5py.File(foreign, "w") as file:
        file.create_dataset("data", data=[1, 2, 3])
    with pytest.raises(CorruptEpisodeError, match="not a crowdteleop episode"):
        read_episode(foreign)
    path = record(tmp_path, 5).finalize("success")
    truncated = tmp_path / "truncated.hdf5"
    truncated.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(CorruptEpisodeError):
        read_episode(truncated)
    with pytest.raises(CorruptEpisodeError, match="not a readable HDF5"):
        read_episode(tmp_path / "missing.hdf5")


@pytest.mark.parametrize("flushes_before_kill", [0, 3])
def test_kill_9_keeps_every_step_up_to_the_last_reported_flush(tmp_path, flushes_before_kill):
    process = subprocess.Popen(
        [sys.executable, str(Path(child.__file__)), str(tmp_path), "killed"],
        stdout=subprocess.PIPE,
        text=True,
        cwd=Path(__file__).resolve().parents[2],
    )
    try:
        assert process.stdout is not None
        assert process.stdout.readline() == "started\n"
        reported = 0
        for _ in range(flushes_before_kill):
            line = process.stdout.readline()
            assert line.startswith("flushed "), line
            reported = int(line.split()[1])
        os.kill(process.pid, signal.SIGKILL)
    finally:
        process.kill()
        process.wait(timeout=30)
    assert process.returncode == -signal.SIGKILL

    partial = read_partial(tmp_path / "killed.wal")
    assert partial.steps >= reported
    if flushes_before_kill:
        assert reported > 0
    assert_holds_child_steps(partial, partial.steps)  # every durable step, bit for bit
    assert partial.model_xml == child.METADATA["model_xml"]
    if partial.steps == 0:  # killed before its first flush: nothing to keep
        assert recover_orphans(tmp_path) == []
        assert not (tmp_path / "killed.wal").exists()
        return
    assert recover_orphans(tmp_path) == [tmp_path / "killed.hdf5"]
    episode = read_episode(tmp_path / "killed.hdf5")
    assert episode.outcome == "crash"
    assert_holds_child_steps(episode, partial.steps)


JSON = st.recursive(
    st.none()
    | st.booleans()
    | st.integers()
    | st.floats(allow_nan=False, allow_infinity=False)
    | st.text(),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(), inner, max_size=3),
    max_leaves=8,
)
FLOATS = st.floats(allow_nan=False, allow_infinity=False, allow_subnormal=True)
ALMOST_FLOAT = FLOATS | st.integers(-(2**70), 2**70) | st.booleans() | st.none()
DEVICES = st.sampled_from([None, "phone", "keyboard", "vr", "scripted", "tablet", ""])


@st.composite
def device_commands(draw) -> dict:
    """Commands shaped as the teleop server's (packed in the log) or nearly so (JSON)."""
    values = {
        "seq": draw(st.integers(-(2**64), 2**64) | st.booleans()),
        "client_time_ms": draw(FLOATS | st.integers(0, 10)),
        "device": draw(DEVICES),
        "position": draw(st.lists(FLOATS, min_size=3, max_size=3) | st.lists(ALMOST_FLOAT)),
        "quaternion": draw(st.lists(FLOATS, min_size=4, max_size=4) | st.lists(ALMOST_FLOAT)),
        "engaged": draw(st.booleans() | st.integers(0, 1)),
        "gripper": draw(st.booleans() | FLOATS | st.none()),
    }
    keys = draw(st.permutations(list(values)))
    keys = keys[: draw(st.sampled_from([7, 7, 7, 6]))]
    command = {key: values[key] for key in keys}
    if draw(st.integers(0, 5)) == 0:
        command["extra"] = draw(JSON)
    return command


CONTACTS = st.lists(
    st.fixed_dictionaries(
        {"robot_part": st.text(), "object": st.text(), "intensity": FLOATS | st.integers()}
    ),
    max_size=3,
)


@st.composite
def episodes(draw) -> list[StepRecord]:
    steps = draw(st.integers(0, 8))
    sizes = draw(st.integers(1, 80)), draw(st.integers(1, 10))
    return [
        StepRecord(
            index=index,
            state=draw(hnp.arrays(np.float64, sizes[0], elements=FLOATS)),
            action=draw(hnp.arrays(np.float64, sizes[1], elements=FLOATS)),
            command=draw(st.dictionaries(st.text(), JSON, max_size=4) | device_commands()),
            server_time=draw(FLOATS),
            step_duration_s=draw(FLOATS),
            reward=draw(FLOATS),
            success=draw(st.booleans()),
            contacts=draw(
                st.lists(st.dictionaries(st.text(), JSON, max_size=3), max_size=3) | CONTACTS
            ),
        )
        for index in range(steps)
    ]


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(episodes(), st.sampled_from(OUTCOMES), st.sampled_from([0.0, 3600.0]))
def test_round_trip_property(steps, outcome, flush_interval_s):
    with tempfile.TemporaryDirectory() as directory:
        recorder = EpisodeRecorder(Path(directory), "prop", {"k": 1}, flush_interval_s)
        for step in steps:
            recorder.append(step)
        partial = read_partial(recorder.wal_path)
        episode = read_episode(recorder.finalize(outcome))
        assert partial.steps == (len(steps) if flush_interval_s == 0.0 else 0)
        quality = episode.metadata.pop("quality")
        assert (episode.steps, episode.outcome, episode.metadata) == (len(steps), outcome, {"k": 1})
        assert "error" not in quality, "any recorded data is measured"
        assert quality["completion_time_s"] == pytest.approx(len(steps) / 20)
        for name in ("state", "action"):
            recorded = getattr(episode, name + "s")
            assert bits(recorded) == bits(np.array([getattr(s, name) for s in steps]))
        for name in ("server_time", "step_duration_s", "reward"):
            recorded = getattr(episode, name if name != "reward" else "rewards")
            assert bits(recorded) == bits(np.array([getattr(s, name) for s in steps]))
        assert episode.success.tolist() == [s.success for s in steps]
        assert episode.commands == [s.command for s in steps]
        assert episode.contacts == [s.contacts for s in steps]
        for recorded, step in zip(partial.commands, steps, strict=False):
            assert json.dumps(recorded) == json.dumps(step.command)  # types and key order
        for recorded, step in zip(episode.contacts, steps, strict=True):
            assert json.dumps(recorded) == json.dumps(step.contacts)


def session_step(index: int, **changes) -> StepRecord:
    """A step as ``TeleopSession._step`` records it (``CommandBoard.raw_command``)."""
    command = {
        "seq": 40 + index,
        "client_time_ms": 1.7e12 + index * 50.5,
        "device": "phone",
        "position": [0.1 * index, -0.0, 5e-324],
        "quaternion": [0.0, 0.0, 0.2, 0.98],
        "engaged": True,
        "gripper": index % 2 == 0,
    }
    fields = {
        "index": index,
        "state": child.make_step(index).state,
        "action": np.arange(8.0) * index,
        "command": command,
        "server_time": 2000.0 + index,
        "step_duration_s": 0.004,
        "reward": np.float64(index % 3),
        "success": np.bool_(index == 4),
        "contacts": [{"robot_part": "gripper0_finger", "object": "cube", "intensity": 0.25}]
        * (index % 3),
    }
    return StepRecord(**{**fields, **changes})


def test_session_steps_are_packed_without_json_and_come_back_exactly(tmp_path):
    steps = [session_step(i) for i in range(6)]
    steps[1].command["device"] = None  # nobody in control
    steps[2].command = dict(reversed(list(steps[2].command.items())))  # any key order
    steps[3].command["gripper"] = 0.5  # a float gripper (scripted operators)
    steps[5].contacts = [{"robot_part": "é", "object": "", "intensity": -0.0}]
    recorder = EpisodeRecorder(tmp_path, "packed", {"k": 1}, flush_interval_s=0.0)
    for step in steps:
        recorder.append(step)
    log = recorder.wal_path.read_bytes()
    assert log.startswith(b"CTWAL02\n")
    assert b'"seq"' not in log and b'"contacts"' not in log  # no JSON
    episode = read_episode(recorder.finalize("success"))
    assert bits(episode.states) == bits(np.array([s.state for s in steps]))
    assert bits(episode.actions) == bits(np.array([s.action for s in steps]))
    assert [json.dumps(c) for c in episode.commands] == [json.dumps(s.command) for s in steps]
    assert [json.dumps(c) for c in episode.contacts] == [json.dumps(s.contacts) for s in steps]
    assert episode.success.tolist() == [False] * 4 + [True, False]
    with h5py.File(tmp_path / "packed.hdf5", "r") as file:
        commands = file["data/demo_0/commands"]
        assert commands["seq"][()].tolist() == list(range(40, 46))
        assert commands["gripper"][()].tolist() == [1, 0, 1, 0.5, 1, 0]
        assert commands["device"].asstr()[()].tolist() == ["phone", "", *["phone"] * 4]
        assert bits(commands["position"][()]) == bits(
            np.array([s.command["position"] for s in steps])
        )


def test_commands_that_do_not_pack_are_kept_as_json_or_as_a_note(tmp_path):
    recorder = EpisodeRecorder(tmp_path, "odd", {"k": 1}, flush_interval_s=0.0)
    odd = [
        {"client_time_ms": 5},  # an int where a float packs
        {"position": (0.0, 1.0, 2.0)},  # a tuple
        {"position": [np.float64(0.5), 1.0, 2.0]},
        {"seq": 2**63},
        {"seq": True},
        {"device": "tablet"},
        {"gripper": 1},
        {"extra": [1, "a"]},
    ]
    expected = []
    for index, change in enumerate(odd):
        step = session_step(index)
        command = {**step.command, **change}
        expected.append(json.loads(json.dumps(command)))
        recorder.append(dataclasses.replace(step, command=command))
    partial = read_partial(recorder.wal_path)
    assert [json.dumps(c) for c in partial.commands] == [json.dumps(c) for c in expected]
    refused_commands = (
        {**session_step(0).command, "position": [0.0, float("nan"), 0.0]},
        {**session_step(0).command, "client_time_ms": float("inf")},
        {**session_step(0).command, "gripper": float("-inf")},
    )
    for command in refused_commands:
        recorder.append(dataclasses.replace(session_step(recorder.steps), command=command))
    refused_contacts = (
        [{"robot_part": "a", "object": "b", "intensity": float("nan")}],
        [{"robot_part": "a", "object": "b", "intensity": 1.0, "x": object()}],
    )
    for contacts in refused_contacts:
        recorder.append(dataclasses.replace(session_step(recorder.steps), contacts=contacts))
    assert recorder.notes == len(refused_commands) + len(refused_contacts)
    notes = read_partial(recorder.wal_path)
    assert all("JSON" in c["unrecordable"] for c in notes.commands[len(odd) :][:3])
    assert all("JSON" in c[0]["unrecordable"] for c in notes.contacts[len(odd) + 3 :])
    odd_contacts = [
        [{"robot_part": "a\x00b", "object": "c", "intensity": 1.0}],  # NUL: as JSON
        [{"object": "c", "robot_part": "a", "intensity": 1.0}],  # other key order
        [{"robot_part": "\ud800", "object": "c", "intensity": 1}],  # a lone surrogate
    ]
    for contacts in odd_contacts:
        recorder.append(dataclasses.replace(session_step(recorder.steps), contacts=contacts))
    episode = read_episode(recorder.finalize("reset"))
    assert [json.dumps(c) for c in episode.contacts[-3:]] == [json.dumps(c) for c in odd_contacts]


def test_version_1_logs_are_still_read_and_recovered(tmp_path):
    """Logs written before the packed layout (magic CTWAL01, JSON commands) stay recoverable."""
    steps = [child.make_step(i) for i in range(4)]
    header = {"episode_id": "old", "created_at": 1.0, "metadata": METADATA}
    records = [b"H" + json.dumps(header).encode()]
    for step in steps:
        head = struct.pack(
            "<qdddBII",
            step.index,
            step.server_time,
            step.step_duration_s,
            step.reward,
            step.success,
            step.state.size,
            step.action.size,
        )
        extras = json.dumps({"command": step.command, "contacts": step.contacts}).encode()
        records.append(b"S" + head + step.state.tobytes() + step.action.tobytes() + extras)
    log = b"CTWAL01\n" + b"".join(struct.pack("<II", len(r), zlib.crc32(r)) + r for r in records)
    (tmp_path / "old.wal").write_bytes(log + b"\x07\x00")  # and a torn tail
    partial = read_partial(tmp_path / "old.wal")
    assert (partial.steps, partial.ignored_tail_bytes) == (4, 2)
    assert recover_orphans(tmp_path) == [tmp_path / "old.hdf5"]
    assert_holds_child_steps(read_episode(tmp_path / "old.hdf5"), 4)


def test_local_storage_put_get_list(tmp_path):
    storage = LocalDirectoryStorage(tmp_path / "store")
    assert isinstance(storage, EpisodeStorage)
    episode = record(tmp_path / "rec", 6).finalize("success")
    uris = {key: storage.put(episode, key) for key in ("lift/a.hdf5", "lift/b c é.hdf5", "can.h5")}
    assert all(uri.startswith("file:///") for uri in uris.values())
    assert storage.list() == ["can.h5", "lift/a.hdf5", "lift/b c é.hdf5"]
    assert storage.list("lift/") == ["lift/a.hdf5", "lift/b c é.hdf5"]
    assert storage.list("nothing") == []
    fetched = storage.get(uris["lift/b c é.hdf5"], tmp_path / "out" / "back.hdf5")
    assert fetched.read_bytes() == episode.read_bytes()
    assert_holds_child_steps(read_episode(fetched), 6)
    assert storage.uri("can.h5") == uris["can.h5"]
    hidden = [p for p in (tmp_path / "store").rglob("*") if p.name.startswith(".")]
    assert hidden == []  # no temporary file left behind


def test_local_storage_put_is_idempotent_and_never_replaces(tmp_path):
    storage = LocalDirectoryStorage(tmp_path / "store")
    first, other = tmp_path / "first", tmp_path / "other"
    first.write_bytes(b"demonstration")
    other.write_bytes(b"another one")
    uri = storage.put(first, "ep.hdf5")
    assert storage.put(first, "ep.hdf5") == uri  # a retry
    with pytest.raises(KeyExistsError, match="different content"):
        storage.put(other, "ep.hdf5")
    assert storage.get(uri, tmp_path / "back").read_bytes() == b"demonstration"
    assert storage.list() == ["ep.hdf5"]


def test_local_storage_refuses_bad_keys_and_uris(tmp_path):
    storage = LocalDirectoryStorage(tmp_path / "store")
    source = tmp_path / "file"
    source.write_bytes(b"x")
    for key in ("", "/abs", "../escape", "a//b", "a/./b", ".hidden", "a\\b", "k" * 1025):
        with pytest.raises(InvalidKeyError):
            storage.put(source, key)
    outside = (tmp_path / "file").as_uri()
    for uri in (outside, "s3://bucket/key", storage.uri("a") + "/../../file"):
        with pytest.raises(InvalidKeyError):
            storage.get(uri, tmp_path / "x")
    with pytest.raises(ObjectNotFoundError):
        storage.get(storage.uri("missing.hdf5"), tmp_path / "x")
    with pytest.raises(FileNotFoundError):
        storage.put(tmp_path / "missing", "key")
    assert storage.list() == []


def test_the_periodic_flush_runs_beside_the_appends_and_reports_failures(tmp_path, monkeypatch):
    """With a flush interval the fsync happens in the recorder's flusher thread: steps become
    durable without a flush call, and a failed background write surfaces on the next append."""
    recorder = EpisodeRecorder(tmp_path, "bg", METADATA, flush_interval_s=0.01)
    for index in range(5):
        recorder.append(child.make_step(index))
        time.sleep(0.02)
    deadline = time.monotonic() + 5
    while recorder.flushed_steps < 4 and time.monotonic() < deadline:
        time.sleep(0.01)
    assert recorder.flushed_steps >= 4
    assert read_partial(recorder.wal_path).steps == recorder.flushed_steps

    real_write, wal_inode = os.write, recorder.wal_path.stat().st_ino

    def disk_full(fd, data):
        if os.fstat(fd).st_ino == wal_inode:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", disk_full)
    time.sleep(0.02)
    recorder.append(child.make_step(5))  # wakes the flusher, which fails
    deadline = time.monotonic() + 5
    with pytest.raises(RecordingError, match="No space left"):
        while time.monotonic() < deadline:
            time.sleep(0.02)
            recorder.append(child.make_step(recorder.steps))
    monkeypatch.undo()
    path = recorder.finalize("success")  # the kept buffer is written now
    assert_holds_child_steps(read_episode(path), recorder.steps)
