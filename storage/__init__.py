"""Durable state of the search service: the ``JobStore`` (jobs, committed rounds, events), the
``PlanStore`` (scene plans, material by material) and the ``ArtifactStore`` (checkpoints, cached
datasets, plans' files). Abstract contracts plus their backends
(``SQLiteJobStore``; ``LocalArtifactStore`` and ``S3ArtifactStore``); the service builds them and
passes them in.

Imports only the standard library (``neuenh`` ← ``storage`` ← ``orchestrator``), and boto3 for
``S3ArtifactStore`` when it is first used: checkpoints travel as bytes (``Bundle.to_bytes()``).
"""

from .artifacts import ArtifactStore, checkpoint_key, content_digest, content_key, validate_key
from .errors import (ConflictError, CorruptArtifactError, IllegalTransitionError, InvalidKeyError,
                     InvalidRecordError, NotFoundError, SchemaVersionError, StorageError)
from .jobs import (TRANSITIONS, UNFINISHED, CandidateRecord, EventKind, EventRecord,
                   FinishedCandidate, HalvingRecord, JobPage, JobRecord, JobStatus, JobStore, RoundKind, RoundRecord,
                   StoreStatistics, WarmupRecord, start_val_loss, trained_epochs)
from .local import LocalArtifactStore
from .lock import OwnerLock, StoreLockedError
from .plans import PLAN_TRANSITIONS, PlanRecord, PlanStatus, PlanStore
from .sqlite import SQLiteDatabase, SQLiteJobStore
from .sqlite_plans import SQLitePlanStore

__all__ = [
    "ArtifactStore", "LocalArtifactStore", "S3ArtifactStore", "checkpoint_key", "content_digest", "content_key",
    "validate_key",
    "JobStore", "SQLiteJobStore", "JobStatus", "TRANSITIONS", "UNFINISHED", "EventKind", "JobRecord", "StoreStatistics", "JobPage", "RoundRecord", "RoundKind", "WarmupRecord", "HalvingRecord",
    "CandidateRecord", "FinishedCandidate", "EventRecord", "start_val_loss", "trained_epochs",
    "StorageError", "NotFoundError", "ConflictError", "IllegalTransitionError", "InvalidRecordError",
    "SchemaVersionError", "InvalidKeyError", "CorruptArtifactError",
    "OwnerLock", "StoreLockedError",
    "PlanStore", "SQLitePlanStore", "PlanStatus", "PlanRecord", "PLAN_TRANSITIONS", "SQLiteDatabase",
]


def __getattr__(name: str):
    """``S3ArtifactStore`` on first use: boto3 is imported only by processes that use a bucket."""
    if name == "S3ArtifactStore":
        from .s3 import S3ArtifactStore

        return S3ArtifactStore
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
