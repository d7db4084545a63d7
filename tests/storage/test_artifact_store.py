"""The ArtifactStore contract, run against every backend of ``conftest.ARTIFACT_BACKENDS``."""

from __future__ import annotations

import hashlib
import threading
import time

import pytest

from neuenh_service.storage import (CorruptArtifactError, InvalidKeyError, NotFoundError, checkpoint_key,
                     content_digest, content_key, validate_key)

GOOD_KEYS = ["a", "jobs/3f2a/rounds/0003/checkpoint.safetensors", "data/x_y-z.1.npz", "-a/b_", "a.b/c..d"]
BAD_KEYS = ["", "/abs/path", "a//b", "a/", "./a", "a/./b", "../a", "a/../b", "a/..", ".hidden",
            "a/.tmp-x", "a.b/..c",
            "a\\b", "a b", "a/b?", "naïve", "x" * 256, "a/" * 600 + "b", "sha256/ab/cd", "sha256",
            "sha256/0/" + "0" * 64, "sha256/00/" + "0" * 63]


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


@pytest.mark.parametrize("key", GOOD_KEYS)
def test_good_keys(key):
    assert validate_key(key) == key


@pytest.mark.parametrize("key", BAD_KEYS + [None, b"a"])
def test_bad_keys(key):
    with pytest.raises(InvalidKeyError) as info:
        validate_key(key)
    assert isinstance(info.value, ValueError)


def test_key_helpers():
    assert checkpoint_key("3f2a", 3) == "jobs/3f2a/rounds/0003/checkpoint.safetensors"
    with pytest.raises(InvalidKeyError):
        checkpoint_key("../etc", 0)
    digest = sha(b"x")
    assert content_key(digest) == f"sha256/{digest[:2]}/{digest}"
    assert content_digest(content_key(digest)) == digest
    assert content_digest("jobs/a/b") is None
    with pytest.raises(InvalidKeyError):
        content_key("ABC")


class TestArtifactStoreContract:
    def test_put_get_roundtrip(self, artifact_store):
        key = checkpoint_key("job1", 0)
        assert not artifact_store.exists(key)
        assert artifact_store.put(key, b"weights-v1") == sha(b"weights-v1")
        assert artifact_store.exists(key) and artifact_store.get(key) == b"weights-v1"
        assert artifact_store.put(key, bytearray(b"weights-v2")) == sha(b"weights-v2")  # replaces
        assert artifact_store.get(key) == b"weights-v2"
        artifact_store.put("empty", memoryview(b""))
        assert artifact_store.get("empty") == b""

    def test_missing_key(self, artifact_store):
        artifact_store.put("jobs/a/b", b"x")
        for key in ("nope", "jobs/a", "jobs/a/b/c"):
            assert not artifact_store.exists(key)
            with pytest.raises(NotFoundError, match=key) as info:
                artifact_store.get(key)
            assert isinstance(info.value, KeyError)
            root = getattr(artifact_store, "root", None)  # a 404's message reaches clients: no server path
            assert root is None or str(root) not in str(info.value)

    def test_delete(self, artifact_store):
        artifact_store.put("a/b", b"x")
        artifact_store.delete("a/b")
        assert not artifact_store.exists("a/b")
        artifact_store.delete("a/b")  # deleting a missing key is fine

    @pytest.mark.parametrize("method", ["put", "get", "exists", "delete"])
    @pytest.mark.parametrize("key", ["", "/etc/passwd", "../x", "a//b", "a/../../b", ".tmp-1"])
    def test_every_method_validates_keys(self, artifact_store, method, key):
        args = (key, b"x") if method == "put" else (key,)
        with pytest.raises(InvalidKeyError):
            getattr(artifact_store, method)(*args)

    def test_data_must_be_bytes(self, artifact_store):
        with pytest.raises(TypeError):
            artifact_store.put("a", "text")
        with pytest.raises(TypeError):
            artifact_store.put_content("text")
        assert not artifact_store.exists("a")

    def test_content_addressing(self, artifact_store):
        data = b"dataset " * 1000
        key = artifact_store.put_content(data)
        assert key == content_key(sha(data)) and artifact_store.get(key) == data
        assert artifact_store.put_content(bytearray(data)) == key  # dedup: same key, same bytes
        assert artifact_store.get(key) == data
        assert artifact_store.put_content(b"other") != key
        with pytest.raises(InvalidKeyError, match="put_content"):
            artifact_store.put(key, data)  # content keys are written only by put_content

    def test_corruption_is_detected(self, artifact_backend):
        store = artifact_backend.open()
        key = store.put_content(b"precious checkpoint")
        artifact_backend.overwrite_raw(key, b"precious checkpoinT")
        with pytest.raises(CorruptArtifactError, match=key):
            store.get(key)

    def test_concurrent_put_content_of_the_same_bytes(self, artifact_store):
        data, keys = bytes(range(256)) * 4096, []
        threads = [threading.Thread(target=lambda: keys.append(artifact_store.put_content(data)))
                   for _ in range(6)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(set(keys)) == 1 and len(keys) == 6
        assert artifact_store.get(keys[0]) == data

    def test_readers_see_old_or_new_never_partial(self, artifact_store):
        old, new, key = b"A" * (2 << 20), b"B" * (3 << 20), "jobs/j/rounds/0000/checkpoint.safetensors"
        artifact_store.put(key, old)
        stop, reads, bad = threading.Event(), [0], []

        def writer():
            for i in range(12):
                artifact_store.put(key, new if i % 2 == 0 else old)
            stop.set()

        def reader():
            while not stop.is_set():
                data = artifact_store.get(key)
                reads[0] += 1
                if data not in (old, new):
                    bad.append(len(data))

        threads = [threading.Thread(target=writer)] + [threading.Thread(target=reader) for _ in range(2)]
        start = time.monotonic()
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert bad == [] and reads[0] > 0 and time.monotonic() - start < 10
        assert artifact_store.get(key) == old

    def test_survives_reopening(self, artifact_backend):
        first = artifact_backend.open()
        key = first.put_content(b"bundle")
        first.put("jobs/a/model", b"m")
        again = artifact_backend.open()
        assert again.get(key) == b"bundle" and again.get("jobs/a/model") == b"m"
