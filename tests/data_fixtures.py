"""What the dataset tests share: a real S3-compatible server (moto's, over HTTP on loopback)
and scripted-operator episodes recorded the way the teleop server records them."""

from __future__ import annotations

import contextlib
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import boto3

from crowdteleop.recording.s3 import S3Config

BUCKET = "demonstrations"
KEYS = {"access_key_id": "testing-key", "secret_access_key": "testing-secret"}
# Who "collected" each scripted episode: two interfaces, two workers, two network conditions.
PEOPLE = [
    {"interface": "phone", "worker_id": "w1", "network_condition": "baseline"},
    {"interface": "keyboard", "worker_id": "w2", "network_condition": "high-delay"},
]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@dataclass
class MotoS3:
    """moto's S3 server in this process; ``stop`` closes its socket (clients get refused),
    ``start`` serves again on the same port with the objects it held."""

    port: int = field(default_factory=free_port)
    _server: object | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self) -> None:
        from moto.server import ThreadedMotoServer

        self._server = ThreadedMotoServer("127.0.0.1", self.port, verbose=False)
        self._server.start()

    def stop(self) -> None:
        assert self._server is not None
        self._server.stop()
        self._server._server.server_close()  # stop() leaves the socket listening
        self._server = None

    def config(self, **fields: object) -> S3Config:
        return S3Config(**{"bucket": BUCKET, "endpoint_url": self.url, **KEYS, **fields})

    def client(self) -> object:
        return boto3.client(
            "s3",
            endpoint_url=self.url,
            region_name="us-east-1",
            aws_access_key_id=KEYS["access_key_id"],
            aws_secret_access_key=KEYS["secret_access_key"],
        )


@contextlib.contextmanager
def moto_s3() -> Iterator[MotoS3]:
    server = MotoS3()
    server.start()
    try:
        yield server
    finally:
        if server._server is not None:
            server.stop()


@contextlib.contextmanager
def moto_with_credentials() -> Iterator[tuple[str, dict[str, str]]]:
    """A moto server process that checks credentials (IAM on): (url, a valid key pair)."""
    port = free_port()
    env = {**os.environ, "INITIAL_NO_AUTH_ACTION_COUNT": "4"}
    process = subprocess.Popen(
        [sys.executable, "-m", "moto.server", "-H", "127.0.0.1", "-p", str(port)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                socket.create_connection(("127.0.0.1", port), 0.2).close()
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.05)
        url = f"http://127.0.0.1:{port}"
        anyone = {"endpoint_url": url, "region_name": "us-east-1", **_aws(KEYS)}
        iam = boto3.client("iam", **anyone)  # the 4 actions moto allows before checking
        iam.create_user(UserName="uploader")
        key = iam.create_access_key(UserName="uploader")["AccessKey"]
        policy = {
            "Version": "2012-10-17",
            "Statement": [{"Effect": "Allow", "Action": "s3:*", "Resource": "*"}],
        }
        iam.put_user_policy(UserName="uploader", PolicyName="s3", PolicyDocument=json.dumps(policy))
        boto3.client("s3", **anyone).create_bucket(Bucket=BUCKET)
        yield (
            url,
            {"access_key_id": key["AccessKeyId"], "secret_access_key": key["SecretAccessKey"]},
        )
    finally:
        process.terminate()
        process.wait(10)


def _aws(keys: dict[str, str]) -> dict[str, str]:
    return {
        "aws_access_key_id": keys["access_key_id"],
        "aws_secret_access_key": keys["secret_access_key"],
    }


def record_lift_episodes(directory: Path, count: int, finalize: bool = True, rig=None) -> list:
    """``count`` scripted lift episodes (seeds 0..count-1), people alternating; ``rig`` (from
    ``scripted_rig``) saves building the simulation again."""
    from crowdteleop.dataset.scripted import record_scripted_episode, scripted_rig

    with contextlib.ExitStack() as stack:
        rig = rig or stack.enter_context(scripted_rig("lift"))
        return [
            record_scripted_episode(
                rig,
                directory,
                f"lift-{seed}",
                seed,
                {**PEOPLE[seed % len(PEOPLE)], "campaign": "tests"},
                finalize=finalize,
            )
            for seed in range(count)
        ]
