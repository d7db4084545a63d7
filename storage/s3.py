"""``ArtifactStore`` in an S3-compatible bucket (AWS S3, MinIO, Ceph, ...): key ``a/b/c`` is the
object ``<prefix>/a/b/c`` of ``bucket``.

Atomic writes: an artifact is written with one ``PutObject`` of its whole content. S3 publishes an
object only once its upload is complete, so a reader gets the old object or the new one, never a
part; a writer that dies mid-upload publishes nothing (and leaves nothing behind to clean up,
unlike the local store's temp files). Each upload carries its Content-MD5, so S3 refuses bytes
damaged on the way (moto, the test server, does not check it; AWS and MinIO do). Content-addressed
keys are checked on read like every backend (``ArtifactStore.get``), so bit rot or a foreign write
under ``sha256/`` is detected.

Transient failures (connection resets, timeouts, 5xx, throttling) are retried by botocore's
"standard" retry mode with jittered exponential backoff, ``max_attempts`` in all; what remains is
raised as ``StorageError`` naming the bucket and endpoint. The constructor checks the bucket once
(``HeadBucket``), so a wrong bucket, endpoint or credentials is a one-line error at startup, not a
failed job later.

Imports boto3, and only here: ``storage`` stays free of S3 for callers that never use it.
"""

from __future__ import annotations

import base64
import hashlib
from typing import Any

import boto3
from botocore.config import Config
from botocore.exceptions import BotoCoreError, ClientError, EndpointConnectionError

from .artifacts import ArtifactStore, Data, validate_key
from .errors import NotFoundError, StorageError

_MISSING = {"404", "NoSuchKey", "NotFound"}
_DENIED = {"403", "AccessDenied", "InvalidAccessKeyId", "SignatureDoesNotMatch"}


class S3ArtifactStore(ArtifactStore):
    def __init__(self, bucket: str, *, prefix: str = "", endpoint_url: str | None = None,
                 region: str | None = None, access_key_id: str | None = None,
                 secret_access_key: str | None = None, max_attempts: int = 5,
                 connect_timeout_s: float = 5.0, read_timeout_s: float = 60.0) -> None:
        """Credentials left ``None`` come from boto3's usual chain (``AWS_*`` variables, the
        shared config, an instance role). Raises ``StorageError`` when the bucket cannot be used."""
        if not bucket:
            raise StorageError("no S3 bucket given")
        self.bucket = bucket
        self.prefix = validate_key(prefix.strip("/")) + "/" if prefix.strip("/") else ""
        self.endpoint_url = endpoint_url
        config = Config(
            retries={"mode": "standard", "total_max_attempts": max_attempts},
            connect_timeout=connect_timeout_s, read_timeout=read_timeout_s,
            # path-style URLs (endpoint/bucket/key) for a self-hosted endpoint: MinIO and the like
            # need no wildcard DNS for bucket sub-domains that way
            s3={"addressing_style": "path" if endpoint_url else "auto"},
            # Older S3-compatible servers reject botocore's newer default CRC checksums; uploads
            # carry a Content-MD5 instead (_write), which every S3 implementation verifies.
            request_checksum_calculation="when_required", response_checksum_validation="when_required",
        )
        self._client = boto3.session.Session().client(
            "s3", endpoint_url=endpoint_url, region_name=region or "us-east-1",
            aws_access_key_id=access_key_id, aws_secret_access_key=secret_access_key, config=config)
        self._call("check", "head_bucket", Bucket=bucket)

    def __repr__(self) -> str:
        return f"S3ArtifactStore({self._where()!r})"

    def _where(self, key: str = "") -> str:
        at = f" at {self.endpoint_url}" if self.endpoint_url else ""
        return f"s3://{self.bucket}/{self.prefix}{key}{at}"

    def _call(self, what: str, operation: str, key: str = "", **kwargs: Any) -> Any:
        """One S3 call (botocore retries transient errors inside it); failures as storage errors."""
        try:
            return getattr(self._client, operation)(**kwargs)
        except ClientError as exc:
            error = exc.response.get("Error", {})
            code = str(error.get("Code", ""))
            if code in _MISSING or code == "NoSuchBucket":
                if operation == "head_bucket" or code == "NoSuchBucket":
                    raise StorageError(f"S3 bucket {self.bucket!r} does not exist"
                                       f"{' at ' + self.endpoint_url if self.endpoint_url else ''}") from None
                raise NotFoundError(f"no artifact {key!r} in {self._where()}") from None
            if code in _DENIED:
                raise StorageError(f"S3 refused access to {self._where(key)} ({code}): check the "
                                   f"credentials and the bucket policy") from None
            raise StorageError(f"S3 {what} of {self._where(key)} failed: {code or exc}") from None
        except EndpointConnectionError:
            raise StorageError(f"cannot reach the S3 endpoint {self.endpoint_url or '(AWS default)'} "
                               f"for bucket {self.bucket!r}") from None
        except BotoCoreError as exc:
            raise StorageError(f"S3 {what} of {self._where(key)} failed: {exc}") from None

    def _write(self, key: str, data: Data) -> None:
        body = bytes(data)
        md5 = base64.b64encode(hashlib.md5(body).digest()).decode()  # the server refuses a damaged upload
        self._call("write", "put_object", key, Bucket=self.bucket, Key=self.prefix + key, Body=body,
                   ContentMD5=md5)

    def _read(self, key: str) -> bytes:
        for attempt in (1, 2):  # botocore retries requests, not a body cut off mid-stream
            answer = self._call("read", "get_object", key, Bucket=self.bucket, Key=self.prefix + key)
            try:
                return answer["Body"].read()
            except BotoCoreError as exc:
                if attempt == 2:
                    raise StorageError(f"S3 read of {self._where(key)} failed: {exc}") from None
        raise AssertionError("unreachable")

    def _exists(self, key: str) -> bool:
        try:
            self._call("check", "head_object", key, Bucket=self.bucket, Key=self.prefix + key)
        except NotFoundError:
            return False
        return True

    def _delete(self, key: str) -> None:
        self._call("delete", "delete_object", key, Bucket=self.bucket, Key=self.prefix + key)

    def close(self) -> None:
        self._client.close()
