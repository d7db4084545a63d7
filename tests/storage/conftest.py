"""Backends under test. Each contract test class runs once per entry of ``JOB_BACKENDS`` /
``ARTIFACT_BACKENDS``; a new backend (S3, Postgres) plugs in here with a harness and nothing else."""

from __future__ import annotations

import sqlite3
import uuid
from collections.abc import Callable
from contextlib import AbstractContextManager, contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from s3_server import CREDENTIALS, MotoServer, s3_server  # noqa: F401  (fixture)
from neuenh_service.storage import ArtifactStore, JobStore, LocalArtifactStore, SQLiteJobStore, SQLitePlanStore


@dataclass
class Harness:
    """Opens stores of one backend on one location (each ``open()`` is a fresh handle on the same
    data, like a restarted process) and closes them all at the end."""

    opener: Callable[[], object]
    overwrite_raw: Callable[[str, bytes], None] | None = None  # bypass the store (bit rot)
    refuse_events: Callable[[], AbstractContextManager] | None = None  # appending an event fails inside
    opened: list = field(default_factory=list)

    def open(self):
        store = self.opener()
        self.opened.append(store)
        return store

    def close_all(self) -> None:
        for store in self.opened:
            close = getattr(store, "close", None)
            if close is not None:
                close()


def _sqlite(request, tmp_path: Path) -> Harness:
    path = tmp_path / "jobs.sqlite3"

    @contextmanager
    def refuse_events():
        """A trigger that aborts every event insert: a write fails after its other statements ran."""
        with sqlite3.connect(path, isolation_level=None) as conn:
            conn.execute("CREATE TRIGGER refuse_events BEFORE INSERT ON events "
                         "BEGIN SELECT RAISE(ABORT, 'events refused by the test'); END")
        try:
            yield
        finally:
            with sqlite3.connect(path, isolation_level=None) as conn:
                conn.execute("DROP TRIGGER refuse_events")

    return Harness(lambda: SQLiteJobStore(path), refuse_events=refuse_events)


def _local(request, tmp_path: Path) -> Harness:
    root = tmp_path / "artifacts"

    def overwrite_raw(key: str, data: bytes) -> None:
        (root / key).write_bytes(data)

    return Harness(lambda: LocalArtifactStore(root), overwrite_raw)


def _s3(request, tmp_path: Path) -> Harness:
    """A fresh bucket on the session's S3 server, under a prefix (as a deployment sharing a
    bucket would use it)."""
    from neuenh_service.storage.s3 import S3ArtifactStore

    server: MotoServer = request.getfixturevalue("s3_server")
    bucket = server.create_bucket(f"test-{uuid.uuid4().hex[:20]}")

    def overwrite_raw(key: str, data: bytes) -> None:
        server.client().put_object(Bucket=bucket, Key=f"neuenh/{key}", Body=data)

    return Harness(lambda: S3ArtifactStore(bucket, prefix="neuenh", endpoint_url=server.url,
                                           access_key_id=CREDENTIALS["aws_access_key_id"],
                                           secret_access_key=CREDENTIALS["aws_secret_access_key"]),
                   overwrite_raw)


JOB_BACKENDS = {"sqlite": _sqlite}
PLAN_BACKENDS = {"sqlite": lambda request, tmp_path: Harness(lambda: SQLitePlanStore(tmp_path / "jobs.sqlite3"))}
ARTIFACT_BACKENDS = {"local": _local, "s3": _s3}


@pytest.fixture(params=sorted(JOB_BACKENDS))
def job_backend(request, tmp_path) -> Harness:
    harness = JOB_BACKENDS[request.param](request, tmp_path)
    yield harness
    harness.close_all()


@pytest.fixture
def job_store(job_backend) -> JobStore:
    return job_backend.open()


@pytest.fixture(params=sorted(ARTIFACT_BACKENDS))
def artifact_backend(request, tmp_path) -> Harness:
    harness = ARTIFACT_BACKENDS[request.param](request, tmp_path)
    yield harness
    harness.close_all()


@pytest.fixture
def artifact_store(artifact_backend) -> ArtifactStore:
    return artifact_backend.open()


@pytest.fixture(params=sorted(PLAN_BACKENDS))
def plan_backend(request, tmp_path) -> Harness:
    harness = PLAN_BACKENDS[request.param](request, tmp_path)
    yield harness
    harness.close_all()
