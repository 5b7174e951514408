"""S3-compatible object storage behind the ``EpisodeStorage`` interface (boto3).

Why boto3 and not s3fs: we need the few calls S3 itself defines (conditional put, head, MD5 of
the body) and their error codes, to tell a store that is down (retry) from one that refuses us
(a missing bucket, wrong credentials: retrying cannot help).

Every put is idempotent and verified: the object is written with ``If-None-Match: *`` (never
replaces an object) and ``Content-MD5`` (the server refuses a body damaged in transit), carries
the file's SHA-256 as metadata, and is read back with ``HEAD`` before ``put`` returns: size,
ETag (the MD5 of a single-part upload) and SHA-256 must match. Putting the same content under
the same key again returns the same URI; different content raises ``KeyExistsError``.
"""

from __future__ import annotations

import base64
import hashlib
import logging
import os
import random
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, Field, SecretStr

from crowdteleop.recording.storage import (
    InvalidKeyError,
    KeyExistsError,
    ObjectNotFoundError,
    StorageError,
    StorageUnavailableError,
    validate_key,
)

log = logging.getLogger(__name__)
T = TypeVar("T")

SHA256_METADATA = "sha256"  # x-amz-meta-sha256
# Error codes that retrying cannot fix: the configuration or the credentials are wrong.
_ACCESS_CODES = {
    "InvalidAccessKeyId",
    "SignatureDoesNotMatch",
    "AccessDenied",
    "InvalidToken",
    "ExpiredToken",
    "AuthorizationHeaderMalformed",
    "403",
}
_BUCKET_CODES = {"NoSuchBucket", "InvalidBucketName", "PermanentRedirect", "301"}


class StorageAccessError(StorageError):
    """The store refused us (credentials) or the bucket does not exist: retrying cannot help."""


class S3Config(BaseModel):
    """Where and how to reach the bucket. Unset credentials and endpoint come from the
    environment the way boto3 reads it (``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``,
    ``AWS_ENDPOINT_URL_S3`` / ``AWS_ENDPOINT_URL``, ``~/.aws``)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    bucket: str = Field(min_length=3, max_length=63)
    prefix: str = Field("", description="prepended to every key, e.g. 'campaign-7/'")
    endpoint_url: str | None = Field(None, description="e.g. http://127.0.0.1:9000; None: AWS")
    region: str = "us-east-1"
    access_key_id: str | None = None
    secret_access_key: SecretStr | None = None
    connect_timeout_s: float = Field(2.0, gt=0)
    read_timeout_s: float = Field(30.0, gt=0)
    attempts: int = Field(5, ge=1, description="tries per operation before giving up")
    backoff_base_s: float = Field(0.2, gt=0, description="first retry delay, doubled each try")
    backoff_max_s: float = Field(10.0, gt=0)


def backoff_delays(base_s: float, max_s: float, rng: random.Random) -> Callable[[int], float]:
    """Exponential backoff with full jitter: try n waits uniform(0, min(max, base * 2**n))."""
    return lambda attempt: rng.uniform(0.0, min(max_s, base_s * 2.0**attempt))


class S3Storage:
    """Episode files as objects ``s3://<bucket>/<prefix><key>``."""

    def __init__(self, config: S3Config) -> None:
        import boto3
        from botocore.config import Config

        self.config = config
        self.prefix = config.prefix
        if self.prefix and not self.prefix.endswith("/"):
            self.prefix += "/"
        secret = config.secret_access_key.get_secret_value() if config.secret_access_key else None
        self._client = boto3.session.Session().client(
            "s3",
            endpoint_url=config.endpoint_url or _endpoint_from_environment(),
            region_name=config.region,
            aws_access_key_id=config.access_key_id,
            aws_secret_access_key=secret,
            config=Config(
                connect_timeout=config.connect_timeout_s,
                read_timeout=config.read_timeout_s,
                retries={"total_max_attempts": 1},  # our backoff decides, not botocore's
                s3={"addressing_style": "path"},
                signature_version="s3v4",
            ),
        )
        self._delay = backoff_delays(config.backoff_base_s, config.backoff_max_s, random.Random())

    # --- the interface ----------------------------------------------------------------------

    def uri(self, key: str) -> str:
        return f"s3://{self.config.bucket}/{self._object_key(key)}"

    def wait_durable(self, key: str, timeout_s: float) -> None:
        """``put`` returns after the store confirmed size and digests: nothing to wait for."""

    def pending_count(self) -> int:
        return 0  # a put here is final

    def close(self) -> None:
        """boto3's client needs no closing; here for the storage interface."""

    def check(self) -> None:
        """Raise ``StorageAccessError`` / ``StorageUnavailableError`` unless the bucket is
        reachable with these credentials (one request)."""
        self._retrying("check", lambda: self._client.head_bucket(Bucket=self.config.bucket))

    def put(self, local_path: Path, key: str) -> str:
        source = Path(local_path)
        if not source.is_file():
            raise ObjectNotFoundError(f"nothing to store: {source} is not a file")
        object_key = self._object_key(key)
        sha256, md5 = _digests(source)
        size = source.stat().st_size
        self._retrying(f"put {key}", lambda: self._put_once(source, object_key, sha256, md5, size))
        return self.uri(key)

    def get(self, uri: str, local_path: Path) -> Path:
        object_key = self._key_of_uri(uri)
        local_path = Path(local_path)
        local_path.parent.mkdir(parents=True, exist_ok=True)
        tmp = local_path.with_name(f".{local_path.name}.{uuid.uuid4().hex}.tmp")

        def download() -> None:
            head = self._head(object_key)
            if head is None:
                raise ObjectNotFoundError(f"no object at {uri}")
            self._client.download_file(self.config.bucket, object_key, str(tmp))
            expected = head.get("Metadata", {}).get(SHA256_METADATA)
            if expected is not None and _digests(tmp)[0] != expected:
                raise StorageUnavailableError(f"{uri} arrived damaged (SHA-256 mismatch)")

        try:
            self._retrying(f"get {uri}", download)
            os.replace(tmp, local_path)
        finally:
            tmp.unlink(missing_ok=True)
        return local_path

    def list(self, prefix: str = "") -> list[str]:
        def pages() -> list[str]:
            keys: list[str] = []
            paginator = self._client.get_paginator("list_objects_v2")
            for page in paginator.paginate(Bucket=self.config.bucket, Prefix=self.prefix + prefix):
                keys.extend(item["Key"][len(self.prefix) :] for item in page.get("Contents", []))
            return keys

        return sorted(self._retrying(f"list {prefix!r}", pages))

    def sha256(self, key: str) -> str | None:
        """The SHA-256 recorded with the object under ``key`` (None: no such object)."""
        head = self._retrying(f"head {key}", lambda: self._head(self._object_key(key)))
        return None if head is None else head.get("Metadata", {}).get(SHA256_METADATA)

    # --- internals --------------------------------------------------------------------------

    def _object_key(self, key: str) -> str:
        validate_key(key)
        full = self.prefix + key
        if len(full.encode()) > 1024:
            raise InvalidKeyError(f"{full!r} is longer than S3's 1024 bytes")
        return full

    def _key_of_uri(self, uri: str) -> str:
        head = f"s3://{self.config.bucket}/{self.prefix}"
        if not uri.startswith(head):
            raise InvalidKeyError(f"{uri!r} is not an object of {head}")
        return self._object_key(uri[len(head) :])

    def _head(self, object_key: str) -> dict[str, Any] | None:
        from botocore.exceptions import ClientError

        try:
            head: dict[str, Any] = self._client.head_object(
                Bucket=self.config.bucket, Key=object_key
            )
            return head
        except ClientError as error:
            if _code(error) in ("404", "NoSuchKey", "NotFound"):
                return None
            raise

    def _put_once(self, source: Path, object_key: str, sha256: str, md5: bytes, size: int) -> None:
        from botocore.exceptions import ClientError

        head = self._head(object_key)
        if head is None:
            try:
                with open(source, "rb") as body:
                    self._client.put_object(
                        Bucket=self.config.bucket,
                        Key=object_key,
                        Body=body,
                        ContentMD5=base64.b64encode(md5).decode(),
                        ContentLength=size,
                        Metadata={SHA256_METADATA: sha256},
                        IfNoneMatch="*",
                    )
            except ClientError as error:
                if _code(error) not in ("PreconditionFailed", "412", "ConditionalRequestConflict"):
                    raise
                # another writer (or our own earlier, unanswered try) got there first
            head = self._head(object_key)
            if head is None:
                raise StorageUnavailableError(f"{object_key} is missing right after its upload")
        stored_sha = head.get("Metadata", {}).get(SHA256_METADATA)
        if stored_sha != sha256:
            raise KeyExistsError(
                f"s3://{self.config.bucket}/{object_key} already holds different content"
            )
        etag = str(head.get("ETag", "")).strip('"')
        if int(head.get("ContentLength", -1)) != size or ("-" not in etag and etag != md5.hex()):
            raise StorageError(
                f"s3://{self.config.bucket}/{object_key} does not match its SHA-256 metadata "
                f"(size {head.get('ContentLength')} vs {size}, ETag {etag} vs {md5.hex()}): "
                "the store damaged it; remove the object and upload again"
            )

    def _retrying(self, what: str, operation: Callable[[], T]) -> T:
        """Run ``operation`` with exponential backoff on errors a retry can fix."""
        for attempt in range(self.config.attempts):
            try:
                return operation()
            except Exception as error:
                failure = self._classify(error, what)
                if not isinstance(failure, StorageUnavailableError):
                    raise failure from error
                if attempt + 1 == self.config.attempts:
                    raise failure from error
                delay = self._delay(attempt)
                log.info("%s (try %d), retrying in %.2f s", failure, attempt + 1, delay)
                time.sleep(delay)
        raise AssertionError("unreachable")

    def _classify(self, error: Exception, what: str) -> Exception:
        from botocore.exceptions import (
            BotoCoreError,
            ClientError,
            EndpointConnectionError,
            NoCredentialsError,
        )

        where = f"{self.config.endpoint_url or 'AWS'} bucket {self.config.bucket!r}"
        if isinstance(error, (StorageError, InvalidKeyError)):
            return error
        if isinstance(error, NoCredentialsError):
            return StorageAccessError(
                f"{what}: no S3 credentials: set access_key_id / secret_access_key or "
                "AWS_ACCESS_KEY_ID / AWS_SECRET_ACCESS_KEY"
            )
        if isinstance(error, ClientError):
            return _classify_answer(error, what, where)
        if isinstance(error, (EndpointConnectionError, BotoCoreError, OSError)):
            return StorageUnavailableError(f"{what}: cannot reach {where}: {error}")
        return error


def _classify_answer(error: Any, what: str, where: str) -> StorageError:
    """What an error the store answered with (botocore's ``ClientError``) means to a caller."""
    code = _code(error)
    if code in _ACCESS_CODES:
        return StorageAccessError(
            f"{what}: {where} refused these credentials ({code}): check the access key and secret"
        )
    if code in _BUCKET_CODES or (code == "404" and what == "check"):
        return StorageAccessError(
            f"{what}: {where} does not exist ({code}): create it or fix the bucket name"
        )
    status = error.response.get("ResponseMetadata", {}).get("HTTPStatusCode", 0)
    if status >= 500 or code in ("SlowDown", "RequestTimeout", "InternalError"):
        return StorageUnavailableError(f"{what}: {where} answered {code}")
    return StorageError(f"{what}: {where} refused the request: {error}")


def _code(error: Any) -> str:
    return str(error.response.get("Error", {}).get("Code", ""))


def _digests(path: Path) -> tuple[str, bytes]:
    """(hex SHA-256, raw MD5) of a file in one read."""
    sha, md5 = hashlib.sha256(), hashlib.md5()
    with open(path, "rb") as file:
        while chunk := file.read(1 << 20):
            sha.update(chunk)
            md5.update(chunk)
    return sha.hexdigest(), md5.digest()


def _endpoint_from_environment() -> str | None:
    return os.environ.get("AWS_ENDPOINT_URL_S3") or os.environ.get("AWS_ENDPOINT_URL") or None
