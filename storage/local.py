"""``ArtifactStore`` in a local directory: key ``a/b/c`` is the file ``<root>/a/b/c``.

Atomic writes (``neuenh.files.atomic_write``): the bytes go to a temporary file ``.tmp-*`` in the
target's directory, are flushed and fsynced, then ``os.replace``d over the target (atomic on POSIX
within one filesystem) and the directory is fsynced. A reader opens either the old file or the new one, never a partial one. A
writer killed mid-write leaves at most a ``.tmp-*`` file, which no key can name (key segments never
start with a dot) and ``remove_stale_temp_files`` deletes.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from neuenh.files import atomic_write

from .artifacts import ArtifactStore, Data
from .errors import ConflictError, NotFoundError

TEMP_PREFIX = ".tmp-"


class LocalArtifactStore(ArtifactStore):
    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)

    def __repr__(self) -> str:
        return f"LocalArtifactStore({str(self.root)!r})"

    def _path(self, key: str) -> Path:
        return self.root.joinpath(*key.split("/"))

    def _write(self, key: str, data: Data) -> None:
        path = self._path(key)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except (FileExistsError, NotADirectoryError):
            raise ConflictError(f"artifact {key!r} cannot be stored: a prefix of it is itself an "
                                f"artifact in {self.root}") from None
        if path.is_dir():
            raise ConflictError(f"artifact {key!r} cannot be stored: other artifacts live under it")
        atomic_write(path, data, prefix=TEMP_PREFIX)

    def _read(self, key: str) -> bytes:
        try:
            return self._path(key).read_bytes()
        except (FileNotFoundError, NotADirectoryError, IsADirectoryError):
            raise NotFoundError(f"no artifact {key!r}") from None  # the message reaches clients: no server path

    def _exists(self, key: str) -> bool:
        return self._path(key).is_file()

    def _delete(self, key: str) -> None:
        path = self._path(key)
        if path.is_file():
            try:
                path.unlink()
            except FileNotFoundError:
                return
            _fsync_dir(path.parent)

    def remove_stale_temp_files(self, older_than_s: float = 3600.0) -> int:
        """Delete temporary files left by writers that died mid-write and are older than
        ``older_than_s`` (younger ones may belong to a write in progress). Returns how many."""
        cutoff = time.time() - older_than_s
        removed = 0
        for tmp in self.root.rglob(TEMP_PREFIX + "*"):
            try:
                if tmp.is_file() and tmp.stat().st_mtime < cutoff:
                    tmp.unlink()
                    removed += 1
            except FileNotFoundError:
                pass
        return removed


def _fsync_dir(directory: Path) -> None:
    """Make a rename or unlink in ``directory`` durable."""
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
