"""What storage raises. Callers (the orchestrator, the API) catch these, never backend errors.

``StorageError`` is the root. The API maps ``NotFoundError`` to 404, ``ConflictError`` to 409 and
``InvalidRecordError``/``InvalidKeyError`` (both also ``ValueError``) to 422.
"""

from __future__ import annotations


class StorageError(Exception):
    """Base class of every error raised by ``storage``."""


class NotFoundError(StorageError, KeyError):
    """No such job, or no such artifact key. A ``KeyError`` so ``except KeyError`` works too."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class ConflictError(StorageError):
    """The request is well formed but clashes with what is stored: an idempotency key reused for a
    different spec, a round out of order or re-committed with different content, a round committed
    to a job that is not RUNNING."""


class IllegalTransitionError(ConflictError):
    """A status change that the job state machine does not allow (e.g. CONVERGED -> RUNNING)."""


class InvalidRecordError(StorageError, ValueError):
    """A record that violates the schema (e.g. two candidates with the same state in one round).
    Nothing of the failed write is stored."""


class SchemaVersionError(StorageError):
    """The database was written by a newer version of neuenh than the one opening it."""


class InvalidKeyError(StorageError, ValueError):
    """An artifact key that is not a safe relative POSIX path."""


class CorruptArtifactError(StorageError):
    """A content-addressed artifact whose bytes no longer hash to its key."""
