"""What only the S3 backend has: its object layout, retries on transient failures, one-line errors
for a wrong bucket or endpoint, and a writer killed mid-upload. Against the session's real S3
server (``s3_server``); the contract itself runs in ``test_artifact_store.py``."""

from __future__ import annotations

import re
import socket
import threading
import time

import pytest

from s3_server import CREDENTIALS
from storage_kit import VERSIONS, WRITTEN_KEY, kill_a_writer_mid_write
from neuenh_service.storage import S3ArtifactStore, StorageError, checkpoint_key


def open_store(url: str, bucket: str, **kw) -> S3ArtifactStore:
    return S3ArtifactStore(bucket, endpoint_url=url, access_key_id=CREDENTIALS["aws_access_key_id"],
                           secret_access_key=CREDENTIALS["aws_secret_access_key"], **kw)


@pytest.fixture
def bucket(s3_server, request) -> str:
    return s3_server.create_bucket(f"t-{abs(hash(request.node.nodeid)) % 10**12}-{time.time_ns() % 10**6}")


def objects(s3_server, bucket: str) -> list[str]:
    return sorted(o["Key"] for o in s3_server.client().list_objects_v2(Bucket=bucket).get("Contents", []))


def test_layout_under_the_prefix(s3_server, bucket):
    store = open_store(s3_server.url, bucket, prefix="/team/neuenh/")
    store.put(checkpoint_key("j", 0), b"0")
    key = store.put_content(b"data")
    assert objects(s3_server, bucket) == sorted([f"team/neuenh/{checkpoint_key('j', 0)}", f"team/neuenh/{key}"])
    bare = open_store(s3_server.url, bucket)  # no prefix: keys are object names
    assert bare.get(f"team/neuenh/{key}") == b"data" and not bare.exists(key)


def test_put_content_writes_once(s3_server, bucket):
    store = open_store(s3_server.url, bucket)
    key = store.put_content(b"x" * 1000)
    first = s3_server.client().head_object(Bucket=bucket, Key=key)["LastModified"]
    time.sleep(1.1)  # S3 times have a resolution of one second
    store.put_content(b"x" * 1000)
    assert s3_server.client().head_object(Bucket=bucket, Key=key)["LastModified"] == first


def test_bad_prefix_is_refused(s3_server, bucket):
    with pytest.raises(ValueError, match="segment"):
        open_store(s3_server.url, bucket, prefix="a/../b")


class FlakyProxy:
    """A TCP proxy on loopback that drops its first ``drops`` connections without an answer (a
    load balancer restarting, a reset) and forwards the rest to ``target``."""

    def __init__(self, target: str, drops: int):
        host, port = target.removeprefix("http://").split(":")
        self.target, self.drops, self.accepted = (host, int(port)), drops, 0
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}"
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.accepted += 1
            if self.accepted <= self.drops:
                conn.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, b"\x01\x00\x00\x00\x00\x00\x00\x00")
                conn.close()  # RST: the request is lost without a response
                continue
            upstream = socket.create_connection(self.target)
            for a, b in ((conn, upstream), (upstream, conn)):
                threading.Thread(target=self._pipe, args=(a, b), daemon=True).start()

    @staticmethod
    def _pipe(src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                dst.sendall(data)
        except OSError:
            pass
        finally:
            for s in (src, dst):
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass

    def close(self) -> None:
        self.sock.close()


def test_transient_failures_are_retried(s3_server, bucket):
    proxy = FlakyProxy(s3_server.url, drops=0)
    try:
        store = open_store(proxy.url, bucket, max_attempts=4)
        proxy.drops = proxy.accepted + 3  # the next three connections are reset
        store.put("jobs/j/model", b"bundle")
        assert proxy.accepted >= 4  # three dropped, then the one that worked
        assert s3_server.client().get_object(Bucket=bucket, Key="jobs/j/model")["Body"].read() == b"bundle"

        proxy.drops = proxy.accepted + 3
        assert store.get("jobs/j/model") == b"bundle"

        once = open_store(proxy.url, bucket, max_attempts=1)
        proxy.drops = proxy.accepted + 1
        with pytest.raises(StorageError, match=re.escape(proxy.url)) as info:
            once.get("jobs/j/model")  # without retries the reset reaches the caller, as one line
        assert "\n" not in str(info.value)
    finally:
        proxy.close()


def test_a_missing_bucket_or_unreachable_endpoint_is_one_line(s3_server):
    with pytest.raises(StorageError) as info:
        open_store(s3_server.url, "no-such-bucket")
    assert str(info.value) == f"S3 bucket 'no-such-bucket' does not exist at {s3_server.url}"

    closed = socket.create_server(("127.0.0.1", 0))
    port = closed.getsockname()[1]
    closed.close()
    start = time.monotonic()
    with pytest.raises(StorageError) as info:
        open_store(f"http://127.0.0.1:{port}", "b", max_attempts=2)
    assert str(info.value) == f"cannot reach the S3 endpoint http://127.0.0.1:{port} for bucket 'b'"
    assert time.monotonic() - start < 10


def test_a_writer_killed_mid_upload_leaves_old_or_new(s3_server, bucket):
    kill_a_writer_mid_write(f"S3ArtifactStore({bucket!r}, endpoint_url={s3_server.url!r}, "
                            "access_key_id='k', secret_access_key='s')", delay_s=0.3)
    assert open_store(s3_server.url, bucket).get(WRITTEN_KEY) in VERSIONS
    assert objects(s3_server, bucket) == [WRITTEN_KEY]  # nothing half-written is left behind
