"""The error every data reader raises for a file it cannot use.

Readers (RGL ``.bsdf``, MERL ``.binary``, NBRDF weights, ...) report a file that is missing,
truncated, malformed or inconsistent as a ``DataError`` (or a subclass) whose message starts with
the file's path and says what is wrong — never a bare numpy or struct traceback. It is a
``ValueError``, so callers that already catch ``ValueError`` keep working.
"""

from __future__ import annotations

import os
from pathlib import Path


class DataError(ValueError):
    """A data file that cannot be read or used; the message names the file and the problem."""


def check_file(path: str | os.PathLike, error: type[DataError] = DataError) -> Path:
    """``path`` as a Path; a missing path or one that is not a regular file is an ``error``."""
    path = Path(path)
    if not path.exists():
        raise error(f"{path}: no such file")
    if not path.is_file():
        raise error(f"{path}: not a regular file")
    return path


def read_bytes(path: str | os.PathLike, error: type[DataError] = DataError) -> bytes:
    """The whole content of ``path``; a missing or unreadable file is an ``error``."""
    path = check_file(path, error)
    try:
        return path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot be read ({exc.strerror or exc})") from None
