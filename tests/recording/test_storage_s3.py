"""Scripted demonstrations stored locally and in a real S3-compatible server (moto's, over HTTP):
checked, idempotent, spooled while the server is down, uploaded exactly once when it returns."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from typer.testing import CliRunner

from crowdteleop.cli import app
from crowdteleop.recording.episode_file import read_episode
from crowdteleop.recording.s3 import S3Storage, StorageAccessError
from crowdteleop.recording.spool import SpooledStorage
from crowdteleop.recording.storage import (
    KeyExistsError,
    LocalDirectoryStorage,
    StorageUnavailableError,
    file_sha256,
)
from crowdteleop.recording.stores import StorageConfig
from crowdteleop.teleop.config import RecordingConfig
from crowdteleop.teleop.episode import FinishedEpisode, store_episode
from tests.fixtures.episodes import PEOPLE, record_lift_episodes
from tests.fixtures.s3 import BUCKET, KEYS, moto_s3, moto_with_credentials


def _finished(episode, number):
    return FinishedEpisode(
        number, episode.recorder.episode_id, episode.outcome, episode.steps, episode.recorder
    )


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


@pytest.fixture(scope="module")
def rig():
    from crowdteleop.dataset.scripted import scripted_rig

    with scripted_rig("lift") as built:
        yield built


@pytest.fixture(scope="module")
def server():
    with moto_s3() as s3:
        s3.client().create_bucket(Bucket=BUCKET)
        yield s3


def test_scripted_episodes_land_in_a_local_directory(rig, tmp_path):
    episodes = record_lift_episodes(tmp_path / "incoming", 1, finalize=False, rig=rig)
    config = RecordingConfig(directory=tmp_path / "store")
    storage = config.open_storage()
    assert isinstance(storage, LocalDirectoryStorage)
    stored = store_episode(_finished(episodes[0], 1), storage, True, {"telemetry": {"rtt_ms": 3}})
    assert stored is not None
    uri = stored.uri
    assert uri.startswith("file://") and uri.endswith("success/lift-0.hdf5")
    assert not list((tmp_path / "incoming").iterdir()), "the recording moved to the store"
    back = storage.get(uri, tmp_path / "back.hdf5")
    episode = read_episode(back)
    assert episode.outcome == "success" and episode.steps == episodes[0].steps
    assert episode.metadata["telemetry"] == {"rtt_ms": 3}
    assert episode.metadata["versions"]["robosuite"] == "1.5.2"
    assert stored.metrics is not None, "measured as it was stored, and told to the caller"
    assert stored.metrics.completion_time_s == pytest.approx(episode.steps / 20)
    assert episode.metadata["quality"] == stored.metrics.model_dump(exclude_none=True)


def test_scripted_episodes_land_in_s3_verified_and_read_back(rig, server, tmp_path):
    episodes = record_lift_episodes(tmp_path / "incoming", 2, finalize=False, rig=rig)
    config = RecordingConfig(
        directory=tmp_path,
        storage=StorageConfig(kind="s3", s3=server.config(prefix="campaign-1")),
    )
    storage = config.open_storage()
    try:
        uris = [
            store_episode(_finished(episode, n), storage, True, PEOPLE[n % 2])
            for n, episode in enumerate(episodes)
        ]
        assert [u.uri for u in uris if u] == [
            f"s3://{BUCKET}/campaign-1/success/lift-{n}.hdf5" for n in range(2)
        ]
        assert storage.pending() == [], "store_episode returned after the store confirmed"
        listed = server.client().list_objects_v2(Bucket=BUCKET, Prefix="campaign-1/")
        assert sorted(o["Key"] for o in listed["Contents"]) == [
            "campaign-1/success/lift-0.hdf5",
            "campaign-1/success/lift-1.hdf5",
        ]
        back = read_episode(
            storage.get(f"s3://{BUCKET}/campaign-1/success/lift-1.hdf5", tmp_path / "back.hdf5")
        )
        assert back.metadata["worker_id"] == "w2" and back.outcome == "success"
        assert np.isfinite(back.states).all() and back.steps == episodes[1].steps
    finally:
        storage.close()


def test_puts_are_idempotent_and_never_replace_an_object(server, tmp_path):
    store = S3Storage(server.config(prefix="idempotent"))
    first, other = tmp_path / "a.hdf5", tmp_path / "b.hdf5"
    first.write_bytes(b"episode bytes" * 1000)
    other.write_bytes(b"something else")
    uri = store.put(first, "x/ep.hdf5")
    assert store.put(first, "x/ep.hdf5") == uri, "a retry returns the same URI"
    with pytest.raises(KeyExistsError, match="different content"):
        store.put(other, "x/ep.hdf5")
    assert store.list("x/") == ["x/ep.hdf5"]
    assert store.sha256("x/ep.hdf5") == file_sha256(first)
    assert store.get(uri, tmp_path / "c.hdf5").read_bytes() == first.read_bytes()


def test_server_stopped_mid_run_every_demonstration_arrives_exactly_once(rig, tmp_path):
    """Two episodes stored, the server stops, two more wait in the spool (the 'stored' rule
    refuses to call them saved), the process 'restarts', the server returns: all four are in
    the bucket once, byte for byte; a crash between upload and unspool re-uploads as a no-op."""
    episodes = record_lift_episodes(tmp_path / "incoming", 4, finalize=False, rig=rig)
    with moto_s3() as server:
        server.client().create_bucket(Bucket=BUCKET)
        s3 = server.config(prefix="run", attempts=2, backoff_base_s=0.05)
        spool_dir = tmp_path / "spool"
        storage = SpooledStorage(S3Storage(s3), spool_dir, backoff_base_s=0.05, backoff_max_s=0.5)
        for n in (0, 1):
            store_episode(_finished(episodes[n], n), storage, True, {})
        server.stop()
        with pytest.raises(StorageUnavailableError, match="spooled"):
            store_episode(_finished(episodes[2], 2), storage, True, {}, store_wait_s=1.0)
        stored = store_episode(_finished(episodes[3], 3), storage, True, {}, saved_when="spooled")
        assert stored is not None and stored.uri == f"s3://{BUCKET}/run/success/lift-3.hdf5"
        assert storage.pending() == ["success/lift-2.hdf5", "success/lift-3.hdf5"]
        assert storage.pending_count() == 2, "the backlog the teleop server's /health reports"
        assert storage.failures >= 1 and "cannot reach" in storage.last_error
        spooled = {
            key: _sha(e.data.read_bytes())
            for key, e in zip(storage.pending(), storage.pending_entries(), strict=True)
        }
        storage.close()  # the process ends with the store still away

        restarted = SpooledStorage(S3Storage(s3), spool_dir, backoff_base_s=0.05, backoff_max_s=0.5)
        try:
            assert restarted.pending() == ["success/lift-2.hdf5", "success/lift-3.hdf5"]
            server.start()
            assert restarted.drain(timeout_s=30), restarted.last_error
            keys = restarted.list()
            assert keys == [f"success/lift-{n}.hdf5" for n in range(4)]
            for key, sha in spooled.items():
                body = server.client().get_object(Bucket=BUCKET, Key=f"run/{key}")["Body"].read()
                assert _sha(body) == sha
                assert read_episode_bytes(body, tmp_path / "check.hdf5").outcome == "success"
            # a crash after the upload, before the entry left the spool: uploaded again, no-op
            copy = tmp_path / "again.hdf5"
            restarted.get(restarted.uri("success/lift-3.hdf5"), copy)
            restarted.put(copy, "success/lift-3.hdf5")
            assert restarted.drain(timeout_s=30)
            assert restarted.list() == keys
            objects = server.client().list_objects_v2(Bucket=BUCKET, Prefix="run/")["Contents"]
            assert len(objects) == 4, "exactly once"
            # and a dataset builds straight from the bucket (credentials from the environment)
            result = CliRunner().invoke(
                app,
                [
                    "dataset",
                    "build",
                    f"s3://{BUCKET}/run/success",
                    "--s3-endpoint",
                    server.url,
                    "--output",
                    str(tmp_path / "from-s3.hdf5"),
                    "--drift-tolerance",
                    "-1",
                ],
                env={
                    "AWS_ACCESS_KEY_ID": KEYS["access_key_id"],
                    "AWS_SECRET_ACCESS_KEY": KEYS["secret_access_key"],
                },
            )
            assert result.exit_code == 0, result.output
            assert "4 demos" in result.output
        finally:
            restarted.close()


def read_episode_bytes(body: bytes, path):
    path.write_bytes(body)
    return read_episode(path)


def test_missing_bucket_and_wrong_credentials_are_clear_and_touch_nothing(tmp_path):
    episode_file = tmp_path / "ep.hdf5"
    episode_file.write_bytes(b"x" * 100)
    with moto_with_credentials() as (url, keys):
        good = S3Storage(_s3_config(url, keys))
        good.put(episode_file, "kept.hdf5")
        missing = S3Storage(_s3_config(url, keys, bucket="no-such-bucket"))
        with pytest.raises(StorageAccessError, match=r"does not exist.*create it"):
            missing.check()
        wrong = S3Storage(_s3_config(url, {**keys, "secret_access_key": "wrong"}))
        with pytest.raises(StorageAccessError, match="refused these credentials"):
            wrong.put(episode_file, "other.hdf5")
        unknown = S3Storage(
            _s3_config(url, {"access_key_id": "AKIANOBODY0000000000", "secret_access_key": "x"})
        )
        with pytest.raises(StorageAccessError, match="credentials"):
            unknown.check()
        # a spool in front of a store that refuses us keeps the episode and says why
        spool = SpooledStorage(wrong, tmp_path / "spool", backoff_base_s=0.05)
        try:
            spool.put(episode_file, "waiting.hdf5")
            assert not spool.wait("waiting.hdf5", 1.0)
            assert "refused these credentials" in spool.last_error
            assert spool.pending() == ["waiting.hdf5"]
        finally:
            spool.close()
        assert good.list() == ["kept.hdf5"], "nothing else in the bucket was touched"
    assert episode_file.read_bytes() == b"x" * 100


def _s3_config(url, keys, bucket=BUCKET):
    from crowdteleop.recording.s3 import S3Config

    return S3Config(bucket=bucket, endpoint_url=url, attempts=2, backoff_base_s=0.05, **keys)
