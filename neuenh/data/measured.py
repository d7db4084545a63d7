"""``load_measured``: one entry point for measured reflectance files, recognised by content.

=========================  ====================================  ==================================
content                    recognised by                         material
=========================  ====================================  ==================================
RGL ``.bsdf``              the ``tensor_file`` magic             ``RGLMaterial`` (continuous)
MERL ``.binary``           the int32 header (90, 90, 180)        ``MERLMaterial`` (continuous)
NBRDF weights ``.npz``     a zip whose arrays are ``names`` and  ``NBRDFMaterial`` (continuous);
                           ``<name>/W1`` ...                     ``name`` picks the network
measurement table ``.npz`` a zip with arrays ``wi, wo, f_r``     ``TableMaterial`` (its samples)
measurement table (CSV)    UTF-8 text whose header names         ``TableMaterial`` (its samples)
                           ``wi_x, ...`` (see neuenh.data.table)
=========================  ====================================  ==================================

The file name and extension play no part. (Image-based captures — a folder of EXR images — hold
one material per texel and have their own reader, ``neuenh.data.capture.read_capture``.) Every material has ``.name``, ``.isotropic``,
``.metadata`` and ``.samples(n, seed)``; continuous ones also ``.evaluate(wi, wo)`` -> f_r (n, 3)
without the cosine, and their samples are Rusinkiewicz-uniform unless ``.samples(n, seed, sampling)``
asks for more (``neuenh.data.directions.Sampling``: near-mirror pairs, every azimuth). ``name`` renames an RGL, MERL or
table material (default: the file's stem) and *selects* the network of an NBRDF file, where it is
required unless the file holds a single network. Anything else is a ``DataError`` naming the file.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from .errors import DataError
from .formats import MEASURED, MEASURED_NOT, TABLE_KEYS, ZIP_MAGIC, detect_format, read_head
from .merl import MERLMaterial, merl_from_table, parse_merl
from .nbrdf import NBRDFMaterial, nbrdf_material, nbrdf_names
from .rgl import RGLMaterial, parse_tensor_file, rgl_from_fields
from .samples import Samples
from .table import TableError, load_table

__all__ = ["MeasuredMaterial", "TableMaterial", "detect_format", "load_measured"]


@dataclass
class TableMaterial:
    """A measurement table: no continuous evaluation, only its stored samples.

    ``samples(n, seed)`` returns every row when ``n`` is at least the table's length, else a
    seeded random subset of ``n`` rows (in stored order). Isotropy is unknown, so ``False``.
    ``weight`` holds the table's optional per-row weights (row order of ``table``); samples do
    not carry them (``Samples`` has no weight field, see neuenh.data.table).
    """

    name: str
    table: Samples = field(repr=False)
    metadata: dict = field(default_factory=dict)
    isotropic: bool = False
    weight: torch.Tensor | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return len(self.table)

    def samples(self, n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        if n < 0:
            raise ValueError(f"number of samples must be >= 0, got {n}")
        t = self.table
        if n >= len(t):
            return t.wi, t.wo, t.f_r
        generator = torch.Generator().manual_seed(seed)
        rows = torch.randperm(len(t), generator=generator)[:n].sort().values
        return t.wi[rows], t.wo[rows], t.f_r[rows]


MeasuredMaterial = RGLMaterial | MERLMaterial | NBRDFMaterial | TableMaterial


def _check_table_members(path: Path) -> None:
    """``read_table`` expects real numeric arrays; reject anything else here, first."""
    try:
        with np.load(path, allow_pickle=False) as npz:
            members = {key: npz[key] for key in sorted(TABLE_KEYS)}
    except Exception as exc:  # noqa: BLE001 - numpy/zipfile/zlib raise many types for a corrupt archive
        raise DataError(f"{path}: not a readable .npz table ({type(exc).__name__}: {exc})") from None
    for key, a in members.items():
        if not isinstance(a, np.ndarray):  # numpy hands back raw bytes for a member that is no .npy
            raise DataError(f"{path}: member {key!r} is not a .npy array")
        if a.dtype.kind not in "iuf":
            raise DataError(f"{path}: {key} must be a real numeric array, got {a.dtype}")


def load_measured(path: str | os.PathLike, name: str | None = None) -> MeasuredMaterial:
    """The measured material in the file at ``path``, whatever its format (see the module doc)."""
    path = Path(path)
    kind = detect_format(path)
    if kind not in MEASURED:
        raise DataError(f"{path}: {MEASURED_NOT[kind]}, not a measured material file (RGL, MERL, NBRDF "
                        "or a measurement table)")
    if kind in ("rgl", "merl"):
        try:
            content = path.read_bytes()
        except OSError as exc:
            raise DataError(f"{path}: cannot be read ({exc.strerror or exc})") from None
        if kind == "rgl":
            return rgl_from_fields(parse_tensor_file(content, path), path, name)
        return merl_from_table(parse_merl(content, path), path, name)
    if kind == "nbrdf":
        if name is None:
            names = nbrdf_names(path)
            if len(names) != 1:
                shown = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
                raise DataError(f"{path}: holds {len(names)} NBRDF networks; choose one with "
                                f"name=... ({shown})")
            name = names[0]
        return nbrdf_material(path, name)
    if read_head(path)[:4] in ZIP_MAGIC:
        _check_table_members(path)
    try:
        table = load_table(path, name)
    except TableError as exc:
        raise DataError(str(exc)) from None
    metadata = {"source": "table", "format": table.format, "path": str(path), "rows": len(table.samples)}
    if table.weight is not None:
        w = table.weight
        metadata["weight"] = {"min": float(w.min()), "max": float(w.max()), "mean": float(w.mean()),
                              "used_in_training": False}
    return TableMaterial(table.samples.names[0], table.samples, metadata, weight=table.weight)
