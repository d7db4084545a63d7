"""Where a command writes, checked before it works: an output folder (``-o DIR``) that exists must be
a folder, so that a fit, an export, a render or a scene plan never ends in a traceback after its work
(the folder itself is made when the first file is written).
"""

from __future__ import annotations

from pathlib import Path


def output_folder(path: Path, flag: str = "-o") -> Path:
    """``path``, unless it exists and is not a folder (a ``ValueError`` naming ``flag`` and it)."""
    if path.exists() and not path.is_dir():
        raise ValueError(f"{flag} {path}: exists and is not a folder")
    return path
