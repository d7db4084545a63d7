"""Durable state of the search service: the ``JobStore`` (jobs, committed rounds, events) and the
``ArtifactStore`` (checkpoints, cached datasets). Abstract contracts plus one backend each
(``SQLiteJobStore``, ``LocalArtifactStore``); the service builds them and passes them in.

Imports only the standard library (``neuenh`` ← ``storage`` ← ``orchestrator``): checkpoints travel
as bytes (``Bundle.to_bytes()``).
"""

from .artifacts import ArtifactStore, checkpoint_key, content_digest, content_key, validate_key
from .errors import (ConflictError, CorruptArtifactError, IllegalTransitionError, InvalidKeyError,
                     InvalidRecordError, NotFoundError, SchemaVersionError, StorageError)
from .jobs import (EVENT_ROUND, EVENT_STATUS, TRANSITIONS, UNFINISHED, CandidateRecord, EventRecord,
                   JobPage, JobRecord, JobStatus, JobStore, RoundRecord)
from .local import LocalArtifactStore
from .lock import OwnerLock, StoreLockedError
from .sqlite import SQLiteJobStore

__all__ = [
    "ArtifactStore", "LocalArtifactStore", "checkpoint_key", "content_digest", "content_key",
    "validate_key",
    "JobStore", "SQLiteJobStore", "JobStatus", "TRANSITIONS", "UNFINISHED", "EVENT_STATUS",
    "EVENT_ROUND", "JobRecord", "JobPage", "RoundRecord", "CandidateRecord", "EventRecord",
    "StorageError", "NotFoundError", "ConflictError", "IllegalTransitionError", "InvalidRecordError",
    "SchemaVersionError", "InvalidKeyError", "CorruptArtifactError",
    "OwnerLock", "StoreLockedError",
]
