"""Measurement files uploaded with a request (``/v1/jobs/{id}/fit``, ``/v1/plan-uploads``).

Each upload is streamed to a folder, read there by the route's reader (a table is refused from its
row count alone, before its values are read: ``neuenh.data.table``), and kept under the name of its
content's SHA-256, so the same file uploaded twice is one file and a plan that names it reads
exactly what was checked. A file that cannot be read is a 422 naming the upload, never the folder.
A plan's files stay while a plan that names them has not ended (``PlanUploads``).
"""

from __future__ import annotations

import hashlib
import os
import re
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import Any, Callable

from fastapi import HTTPException, UploadFile, status

from neuenh.data.errors import DataError
from neuenh.data.formats import fit_kind
from neuenh.data.table import TableTooLarge
from neuenh_service.storage import PlanRecord, PlanStore

CHUNK = 1 << 20
PLAN_UPLOADS = "uploads"  # under the data directory: the measured files sent with scenes, by digest
UPLOADABLE = "measurement tables (.npz, CSV), RGL .bsdf or MERL .binary files"


def uploaded_kind(path: Path) -> str:
    """What an uploaded file is, told by its content (``neuenh.data.formats.fit_kind``): ``"table"``
    or a measured file pairs are drawn from; anything else (NBRDF weights, an EXR capture, junk) is a
    ``DataError`` naming it."""
    try:
        return fit_kind(path)
    except DataError as exc:
        raise DataError(f"{exc}; uploads are {UPLOADABLE}") from None


@dataclass(frozen=True)
class Received:
    filename: str  # the upload's own file name, without folders
    name: str  # the material's name: the file's stem in safe characters
    path: Path  # where it is kept: FOLDER/<sha256>
    value: Any  # what the reader made of it
    new: bool  # kept by this request (no earlier one had sent the same content)


def discard(received: list[Received]) -> None:
    """Remove what this request alone kept (a request refused after its files arrived)."""
    for r in received:
        if r.new:
            r.path.unlink(missing_ok=True)


def receive(files: list[UploadFile], folder: Path, read: Callable[[Path, str], Any], max_rows: int) -> list[Received]:
    """Every upload kept in ``folder`` and read by ``read(path, name)``; two uploads that would be
    the same material, an unreadable file, or a table over ``max_rows`` rows (the service's
    per-material limit) are a 422, and then nothing this request kept stays."""
    names = [material_name(f.filename, i) for i, f in enumerate(files)]
    if len(set(names)) != len(names):
        raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                            f"files: two uploads share a material name ({', '.join(names)}); rename one")
    folder.mkdir(parents=True, exist_ok=True)
    received: list[Received] = []
    try:
        for upload, name in zip(files, names):
            received.append(_receive_one(upload, name, folder, read, max_rows))
    except BaseException:
        discard(received)
        raise
    return received


def _receive_one(upload: UploadFile, name: str, folder: Path, read, max_rows: int) -> Received:
    shown = PurePath((upload.filename or name).replace("\\", "/")).name or name
    digest = hashlib.sha256()
    fd, tmp = tempfile.mkstemp(prefix=".upload-", dir=folder)
    try:
        with os.fdopen(fd, "wb") as out:
            while chunk := upload.file.read(CHUNK):
                digest.update(chunk)
                out.write(chunk)
        try:
            value = read(Path(tmp), name)
        except TableTooLarge as exc:  # refused from the row count alone, before reading values
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT,
                                f"{shown}: {exc.counted} measurements exceed this service's limit of "
                                f"{max_rows} per material (NEUENH_MAX_SAMPLES)") from None
        except DataError as exc:  # its message names the temporary path: name the upload instead
            raise HTTPException(status.HTTP_422_UNPROCESSABLE_CONTENT, str(exc).replace(tmp, shown)) from None
        kept = folder / digest.hexdigest()
        new = not kept.exists()
        os.replace(tmp, kept)  # whole or not at all; the same content lands on the same name
        return Received(shown, name, kept, value, new)
    finally:
        Path(tmp).unlink(missing_ok=True)


def material_name(filename: str | None, index: int) -> str:
    """The upload's file name without folders and suffix, reduced to safe characters."""
    stem = PurePath((filename or "").replace("\\", "/")).name.split(".")[0]
    return re.sub(r"[^A-Za-z0-9_-]+", "_", stem).strip("_") or f"material_{index}"


class PlanUploads:
    """The files sent with scenes (``folder``), removed once no plan that names them is left to run.
    ``lock`` is the one uploads are received under, so a request that keeps a file and queues its
    plan is never between the two while a file is removed."""

    def __init__(self, folder: Path, lock: threading.Lock):
        self.folder, self.lock = folder.resolve(), lock

    def named_by(self, plan: PlanRecord) -> set[Path]:
        """The kept files ``plan``'s scene reads."""
        paths = {Path(m["path"]).resolve() for m in plan.scene.get("materials", [])
                 if isinstance(m, dict) and isinstance(m.get("path"), str)}
        return {p for p in paths if p.parent == self.folder}

    def sweep(self, plans: PlanStore) -> list[Path]:
        """At start: remove what no unfinished plan names (left by a stop between a plan's end and
        its release, or by a request cut off mid-upload); the removed files."""
        if not self.folder.is_dir():
            return []
        with self.lock:
            still = set().union(*(self.named_by(p) for p in plans.unfinished_plans()))
            gone = sorted(p for p in self.folder.iterdir() if p.is_file() and p not in still)
            for path in gone:
                path.unlink(missing_ok=True)
        return gone

    def release(self, ended: PlanRecord, plans: PlanStore) -> list[Path]:
        """Remove the files of the ended plan that no unfinished plan names; the removed ones."""
        with self.lock:
            still = set().union(*(self.named_by(p) for p in plans.unfinished_plans()))
            gone = sorted(self.named_by(ended) - still)
            for path in gone:
                path.unlink(missing_ok=True)
        return gone
