"""Writing files atomically: a reader sees the old file or the whole new one, never a part.

``atomic_write(path, data)`` is the one way the project writes a file others may read: the data goes
to a temporary file in the same folder (a unique name, so concurrent writers never share one), is
flushed to disk (fsync), given its permissions (default 0644: a model or an export is meant to be
shared; ``mkstemp`` would leave 0600) and renamed over ``path`` (atomic on POSIX within one file
system); the folder is then fsynced so the rename itself survives a crash. On any failure the
temporary file is removed and ``path`` keeps its old content (or stays absent). ``data`` is bytes,
text (UTF-8), or a function that writes the temporary file itself (a library's ``save(path)``).
The temporary file is ``.<name>.<random>.tmp<suffix>`` (``prefix`` replaces ``.<name>.``): it keeps
the target's suffix, so writers that choose the format by it (``savefig``, ``np.savez``, which adds
``.npz`` to any other name) write the right thing, and its leading dot hides it from listings —
not from a glob such as ``*.json``: a writer killed mid-write leaves it behind, so a reader of a folder
skips what ``is_temporary`` names.
``atomic_write_digest`` does the same and returns the SHA-256 of exactly what was written.

``existing(path)``: the file's status, or None for a name that names nothing — including one no file
system can hold (too long, a NUL), for which ``Path.exists`` and ``Path.stat`` raise instead.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path
from typing import Callable

Data = bytes | bytearray | memoryview | str | Callable[[Path], object]

__all__ = ["atomic_write", "atomic_write_digest", "existing", "is_temporary"]

_TEMPORARY = ".tmp"  # the suffix a temporary file's name carries before the target's own


def atomic_write(path: str | os.PathLike, data: Data, *, mode: int | None = 0o644, prefix: str | None = None) -> Path:
    """Write ``data`` to ``path`` atomically (module doc); returns ``path``. ``mode``: the file's
    permission bits (None keeps the temporary file's 0600); ``prefix``: of the temporary's name."""
    path = Path(path)
    _write(path, data, mode, prefix, digest=False)
    return path


def atomic_write_digest(path: str | os.PathLike, data: Data, *, mode: int | None = 0o644) -> str:
    """``atomic_write``, returning the SHA-256 (hex) of the bytes written, read back from the
    temporary file before the rename (so it is this writer's, whatever another writer does next)."""
    return _write(Path(path), data, mode, None, digest=True)


def existing(path: str | os.PathLike) -> os.stat_result | None:
    """``path``'s status (symbolic links followed), or None when it names nothing (module doc)."""
    try:
        return Path(path).stat()
    except (OSError, ValueError):  # ENOENT, ENAMETOOLONG, ENOTDIR, ...; ValueError: an embedded NUL
        return None


def is_temporary(path: str | os.PathLike) -> bool:
    """Whether ``path`` is named as ``atomic_write``'s temporary files are (default prefix):
    ``.<name>.<random>.tmp<suffix>``, possibly left half-written by a killed writer."""
    path = Path(path)  # the random part has no dot: ``_TEMPORARY`` is the last suffix or the one before it
    return path.name.startswith(".") and _TEMPORARY in path.suffixes[-2:]


def _write(path: Path, data: Data, mode: int | None, prefix: str | None, digest: bool) -> str:
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=prefix or f".{path.name}.", suffix=_TEMPORARY + path.suffix)
    tmp = Path(name)
    try:
        if callable(data):
            os.close(fd)
            fd = -1
            data(tmp)
            fd = os.open(tmp, os.O_RDONLY)
        else:
            with os.fdopen(fd, "wb", closefd=False) as f:
                f.write(data.encode() if isinstance(data, str) else bytes(data))
        os.fsync(fd)
        sha = _sha256(fd) if digest else ""
        os.close(fd)
        fd = -1
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, path)
        _fsync_folder(path.parent)
        return sha
    except BaseException:
        if fd >= 0:
            os.close(fd)
        tmp.unlink(missing_ok=True)
        raise


def _sha256(fd: int) -> str:
    with open(fd, "rb", closefd=False) as f:
        f.seek(0)
        return hashlib.file_digest(f, "sha256").hexdigest()


def _fsync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` durable (POSIX: fsync the directory); a no-op where folders
    cannot be opened (Windows)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
