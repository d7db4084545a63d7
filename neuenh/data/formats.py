"""What a data file holds, from its content (never its name): the one place that sniffs formats.

``detect_format(path)`` is one of

* measured materials (``neuenh.data.measured.load_measured`` reads them): ``"rgl"`` (an RGL
  ``tensor_file``), ``"merl"`` (a MERL ``.binary``), ``"nbrdf"`` (NBRDF weights, ``.npz``),
  ``"table"`` (a measurement table, ``.npz`` with ``wi, wo, f_r`` or CSV);
* ``"capture"``: an image-based capture (``neuenh.data.capture``): a folder holding
  ``capture.json``, or a JSON file with an ``images`` list;
* ``"exr"``: an OpenEXR image (a parameter image when its header carries ``neuenh``);
* ``"dataset"``: a materialised training dataset (``.npz`` written by ``neuenh data sample``).

Anything else is a ``DataError`` naming the file and what its first bytes are.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from .draws import DRAWN_KINDS
from .errors import DataError
from .merl import looks_like_merl
from .nbrdf import is_nbrdf_keys
from .rgl import is_tensor_file
from .table import looks_like_csv_table

__all__ = ["CAPTURE_JSON", "MEASURED", "MEASURED_NOT", "TABLE_KEYS", "ZIP_MAGIC", "detect_format", "fit_kind",
           "read_head"]

CAPTURE_JSON = "capture.json"
MEASURED = ("rgl", "merl", "nbrdf", "table")
MEASURED_NOT = {"capture": "an image-based capture (one material per texel: read it with neuenh.data.capture)",
                "exr": "an OpenEXR image", "dataset": "a materialised training dataset (neuenh data sample)"}
NOT_MEASURED_NBRDF = "NBRDF network weights (a model, not measurements)"  # what a fit (fit_kind) calls them
ZIP_MAGIC = (b"PK\x03\x04", b"PK\x05\x06")
EXR_MAGIC = b"\x76\x2f\x31\x01"
TABLE_KEYS = {"wi", "wo", "f_r"}
DATASET_KEYS = {"names", "recipe", "train_wi", "val_wi", "train_material"}
_HEAD_BYTES = 4096  # enough for the binary magics and a CSV header after a few comment lines
_MAX_CAPTURE_JSON = 64 << 20


def read_head(path: Path) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(_HEAD_BYTES)
    except OSError as exc:
        raise DataError(f"{path}: cannot be read ({exc.strerror or exc})") from None


def fit_kind(path: str | os.PathLike) -> str:
    """What a fit reads at ``path``: ``"table"`` (its rows) or one of ``draws.DRAWN_KINDS`` (a measured
    file pairs are drawn from); any other kind is a DataError naming what the file is."""
    kind = detect_format(path)
    if kind == "table" or kind in DRAWN_KINDS:
        return kind
    what = NOT_MEASURED_NBRDF if kind == "nbrdf" else MEASURED_NOT.get(kind, f"a {kind} file")
    raise DataError(f"{path}: {what}")


def detect_format(path: str | os.PathLike) -> str:
    """The kind of data at ``path`` (see the module doc)."""
    path = Path(path)
    try:
        is_folder, is_file = path.is_dir(), path.is_file()
    except (OSError, ValueError) as exc:  # a name too long, a NUL: pathlib lets those through
        raise DataError(f"{path}: not a usable path ({getattr(exc, 'strerror', None) or exc})") from None
    if is_folder:
        if (path / CAPTURE_JSON).is_file():
            return "capture"
        raise DataError(f"{path}: not a regular file (a folder, and without the {CAPTURE_JSON} of a capture)")
    if not is_file:  # asked only now: a usable name, neither a folder nor a regular file
        raise DataError(f"{path}: not a regular file" if path.exists() else f"{path}: no such file")
    head = read_head(path)
    if head[:4] == EXR_MAGIC:
        return "exr"
    if is_tensor_file(head):
        return "rgl"
    if looks_like_merl(head, path.stat().st_size):
        return "merl"
    if head[:4] in ZIP_MAGIC:
        return _zip_kind(path)
    if head[:1] == b"{" and _is_capture_json(path):
        return "capture"
    if looks_like_csv_table(head):
        return "table"
    raise DataError(f"{path}: unrecognised content (not an RGL tensor_file, a MERL .binary, NBRDF weights, "
                    f"a measurement table (.npz or CSV), a capture or an EXR image); first bytes {head[:16]!r}")


def _zip_kind(path: Path) -> str:
    try:
        with np.load(path, allow_pickle=False) as npz:
            keys = list(npz.files)
    except Exception as exc:  # noqa: BLE001 - numpy/zipfile raise many types for a corrupt archive
        raise DataError(f"{path}: a zip archive but not a readable .npz ({type(exc).__name__}: {exc})") from None
    if is_nbrdf_keys(keys):
        return "nbrdf"
    if TABLE_KEYS <= set(keys):
        return "table"
    if DATASET_KEYS <= set(keys):
        return "dataset"
    shown = ", ".join(keys[:10]) + (", ..." if len(keys) > 10 else "")
    raise DataError(f"{path}: an .npz that is neither NBRDF weights (names, <name>/W1, ...), a measurement "
                    f"table (wi, wo, f_r) nor a dataset (names, recipe, train_wi, ...); it holds [{shown}]")


def _is_capture_json(path: Path) -> bool:
    """A JSON object with an ``images`` list (cheap: no validation, that is the reader's)."""
    if path.stat().st_size > _MAX_CAPTURE_JSON:
        return False
    try:
        return isinstance(json.loads(path.read_bytes()).get("images"), list)
    except (OSError, ValueError, AttributeError):
        return False
