"""One orchestrator per job store: an exclusive lock on a file beside the store.

Two processes running jobs from the same store (``neuenh serve`` twice, or a server and
``neuenh search`` on one data directory) would train the same job twice and race to commit its
rounds. Whoever runs jobs first takes ``OwnerLock(data_dir / "owner.lock")``; the second gets
``StoreLockedError`` naming the owner (its command, pid, host and start time).

The lock is ``flock(2)``: the kernel drops it when the owning process dies, however it dies, so a
crash never leaves a stale lock behind. The owner's description is written into the file for the
error message only; it is never trusted as the lock itself. Local filesystems only (NFS ``flock``
semantics vary): on a cluster the job store lives on the api's own volume (ARCHITECTURE §2).
"""

from __future__ import annotations

import fcntl
import json
import os
import socket
import sys
import time
from pathlib import Path

from .errors import StorageError


class StoreLockedError(StorageError):
    """Another process already owns the store."""


class OwnerLock:
    """``with OwnerLock(path, owner="neuenh serve"):`` — held until ``release()`` or exit."""

    def __init__(self, path: str | os.PathLike, owner: str):
        self.path = Path(path)
        self.owner = owner
        self._fd: int | None = None

    def acquire(self) -> "OwnerLock":
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _describe(self.path)
            os.close(fd)
            raise StoreLockedError(
                f"{self.path.parent} is in use by {holder}; one process runs the jobs of a store at a "
                f"time: stop it, or use another data directory") from None
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({"owner": self.owner, "pid": os.getpid(), "host": socket.gethostname(),
                                 "since": time.strftime("%Y-%m-%d %H:%M:%S"),
                                 "argv": sys.argv}).encode())
        self._fd = fd
        return self

    def release(self) -> None:
        if self._fd is not None:
            os.ftruncate(self._fd, 0)
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def __enter__(self) -> "OwnerLock":
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def _describe(path: Path) -> str:
    try:
        info = json.loads(path.read_text() or "{}")
        return f"{info['owner']} (pid {info['pid']} on {info['host']}, since {info['since']})"
    except (OSError, ValueError, KeyError, TypeError):
        return "another process"
