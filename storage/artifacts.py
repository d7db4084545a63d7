"""The artifact store: immutable-ish blobs (round checkpoints, cached datasets) under string keys.

This module holds the contract (``ArtifactStore``), key rules and key naming. Backends
(``storage.local.LocalArtifactStore`` today, S3 later) implement four primitives on keys that are
already validated; the public methods, key validation and content addressing live here, so every
backend behaves the same.

**Keys** are relative POSIX paths of segments made of ``A-Z a-z 0-9 . _ -`` that do not start with
a dot: ``jobs/<id>/rounds/0003/checkpoint.safetensors``. Rejected (``InvalidKeyError``): empty
keys, absolute paths, ``..``/``.``/hidden segments, empty segments (``a//b``, ``a/``),
backslashes, keys longer than 1024 characters. The prefix ``sha256/`` is reserved for content
addressing.

**Content addressing**: ``put_content(data)`` stores ``data`` under ``sha256/<2 hex>/<64 hex>`` (its
SHA-256) and returns that key; storing the same bytes again writes nothing. ``get`` of such a key
re-hashes the bytes and raises ``CorruptArtifactError`` if they no longer match.
"""

from __future__ import annotations

import hashlib
import re
from abc import ABC, abstractmethod

from .errors import CorruptArtifactError, InvalidKeyError

CONTENT_PREFIX = "sha256"
MAX_KEY_LENGTH = 1024
_SEGMENT = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,254}")
_DIGEST = re.compile(r"[0-9a-f]{64}")

Data = bytes | bytearray | memoryview


def validate_key(key: str) -> str:
    """Return ``key`` if it is a valid artifact key, else raise ``InvalidKeyError`` saying why."""
    if not isinstance(key, str):
        raise InvalidKeyError(f"an artifact key is a string, got {type(key).__name__}")
    if not key:
        raise InvalidKeyError("an artifact key must not be empty")
    if len(key) > MAX_KEY_LENGTH:
        raise InvalidKeyError(f"artifact key longer than {MAX_KEY_LENGTH} characters")
    if key.startswith("/"):
        raise InvalidKeyError(f"artifact key {key!r} must be relative, not absolute")
    if "\\" in key:
        raise InvalidKeyError(f"artifact key {key!r} must use '/' separators, not backslashes")
    for segment in key.split("/"):
        if not segment:
            raise InvalidKeyError(f"artifact key {key!r} has an empty segment")
        if segment in (".", ".."):
            raise InvalidKeyError(f"artifact key {key!r} must not contain '{segment}' segments")
        if not _SEGMENT.fullmatch(segment):
            raise InvalidKeyError(
                f"artifact key {key!r}: segment {segment!r} must be 1-255 characters of "
                f"A-Z a-z 0-9 . _ - and must not start with a dot")
    if key.split("/", 1)[0] == CONTENT_PREFIX and content_digest(key) is None:
        raise InvalidKeyError(f"artifact key {key!r}: the prefix '{CONTENT_PREFIX}/' is reserved for "
                              f"content-addressed keys '{CONTENT_PREFIX}/<2 hex>/<64 hex>'")
    return key


def content_key(digest: str) -> str:
    """The key of the content whose SHA-256 hex digest is ``digest``."""
    if not _DIGEST.fullmatch(digest):
        raise InvalidKeyError(f"not a lowercase SHA-256 hex digest: {digest!r}")
    return f"{CONTENT_PREFIX}/{digest[:2]}/{digest}"


def content_digest(key: str) -> str | None:
    """The SHA-256 digest a content-addressed key names, or None for any other key."""
    parts = key.split("/")
    if len(parts) == 3 and parts[0] == CONTENT_PREFIX and _DIGEST.fullmatch(parts[2]) \
            and parts[1] == parts[2][:2]:
        return parts[2]
    return None


def checkpoint_key(job_id: str, round_index: int) -> str:
    """Where the winner checkpoint (``Bundle.to_bytes()``) of a committed round is stored."""
    if round_index < 0:
        raise ValueError(f"round index must be >= 0, got {round_index}")
    return validate_key(f"jobs/{job_id}/rounds/{round_index:04d}/checkpoint.safetensors")


def sha256(data: Data) -> str:
    return hashlib.sha256(data).hexdigest()


class ArtifactStore(ABC):
    """Blobs under keys. Every backend honours this contract (checked by
    ``tests/storage/test_artifact_store.py`` against each one):

    * ``put(key, data)`` stores ``data`` under ``key`` (replacing what was there) and returns its
      SHA-256 hex digest. The write is atomic: a concurrent or later reader sees the old bytes or
      the new ones, never a part, also if the writer dies mid-write; a failed ``put`` leaves the
      old bytes.
    * ``get(key)`` returns the bytes, ``NotFoundError`` (a ``KeyError``) for a missing key, and
      ``CorruptArtifactError`` for a content-addressed key whose bytes do not hash to it.
    * ``exists(key)``; ``delete(key)`` (no error if the key is missing).
    * ``put_content(data)`` stores ``data`` under its content key and returns the key, writing
      nothing when that key already exists.
    * Keys are validated (``validate_key``) by every method; ``put`` refuses content keys.
    * One store object may be used from many threads and processes at once.
    * ``close()`` releases what the store holds open (connections); nothing for a directory.
    """

    def put(self, key: str, data: Data) -> str:
        validate_key(key)
        if content_digest(key) is not None:
            raise InvalidKeyError(f"artifact key {key!r} is content-addressed; store it with put_content")
        data = _check_data(data)
        digest = sha256(data)
        self._write(key, data)
        return digest

    def get(self, key: str) -> bytes:
        validate_key(key)
        data = self._read(key)
        expected = content_digest(key)
        if expected is not None and (actual := sha256(data)) != expected:
            raise CorruptArtifactError(
                f"artifact {key!r} is corrupt: its {len(data)} bytes hash to {actual}")
        return data

    def exists(self, key: str) -> bool:
        return self._exists(validate_key(key))

    def delete(self, key: str) -> None:
        self._delete(validate_key(key))

    def put_content(self, data: Data) -> str:
        data = _check_data(data)
        key = content_key(sha256(data))
        if not self._exists(key):
            self._write(key, data)
        return key

    def close(self) -> None:
        """Release connections; the store is not used afterwards."""

    # Backend primitives: ``key`` is valid; ``_read`` raises NotFoundError for a missing key.

    @abstractmethod
    def _write(self, key: str, data: Data) -> None:
        """Atomically store ``data`` under ``key``."""

    @abstractmethod
    def _read(self, key: str) -> bytes: ...

    @abstractmethod
    def _exists(self, key: str) -> bool: ...

    @abstractmethod
    def _delete(self, key: str) -> None: ...


def _check_data(data: Data) -> Data:
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError(f"artifact data must be bytes-like, got {type(data).__name__}")
    return data
