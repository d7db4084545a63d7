"""A user's own measurements as a table: ``.npz`` with keys ``wi``, ``wo``, ``f_r`` (and optional
``weight``), one material per file.

Directions are unit vectors in the local frame (z = surface normal), ``f_r`` is RGB without the
cosine factor. Everything is validated and every problem is reported as a ``TableError`` that
names the file and what is wrong.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np
import torch

from .errors import DataError
from .samples import Samples


class TableError(DataError):
    """A measurement table that cannot be used; the message names the file and the problem."""


def read_table(path: str | os.PathLike, name: str | None = None) -> Samples:
    path = Path(path)
    if not path.is_file():
        raise TableError(f"{path}: no such file")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
        raise TableError(f"{path}: not a readable .npz table ({exc})") from None
    missing = [k for k in ("wi", "wo", "f_r") if k not in arrays]
    if missing:
        raise TableError(f"{path}: missing array(s) {missing} (a table needs wi, wo, f_r)")
    n = None
    for key in ("wi", "wo", "f_r"):
        a = arrays[key]
        if not isinstance(a, np.ndarray):  # a member that is not a .npy array comes back as bytes
            raise TableError(f"{path}: {key} is not an array")
        if a.ndim != 2 or a.shape[1] != 3 or not (
            np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)
        ):
            raise TableError(f"{path}: {key} must be a numeric (n, 3) array, got {a.dtype}{a.shape}")
        if n is not None and a.shape[0] != n:
            raise TableError(f"{path}: wi, wo and f_r must have the same length, got {arrays['wi'].shape[0]}, "
                             f"{arrays['wo'].shape[0]}, {arrays['f_r'].shape[0]}")
        n = a.shape[0]
        if not np.isfinite(a).all():
            raise TableError(f"{path}: {key} has non-finite values (first at row {int(np.argwhere(~np.isfinite(a))[0, 0])})")
    if n == 0:
        raise TableError(f"{path}: the table is empty")
    for key in ("wi", "wo"):
        norms = np.linalg.norm(arrays[key], axis=1)
        bad = np.abs(norms - 1) > 1e-3
        if bad.any():
            raise TableError(f"{path}: {key} must hold unit vectors (row {int(np.argmax(bad))} has norm {norms[bad][0]:.4g})")
    if (arrays["f_r"] < 0).any():
        raise TableError(f"{path}: f_r has negative values (row {int(np.argwhere(arrays['f_r'] < 0)[0, 0])})")
    t = {k: torch.as_tensor(arrays[k], dtype=torch.float32) for k in ("wi", "wo", "f_r")}
    return Samples(t["wi"], t["wo"], t["f_r"], torch.zeros(n, dtype=torch.long), (name or path.stem,))


def write_table(path: str | os.PathLike, wi, wo, f_r) -> Path:
    """Write a table that ``read_table`` reads (atomically)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp.npz")
    np.savez(tmp, wi=np.asarray(wi, dtype=np.float32), wo=np.asarray(wo, dtype=np.float32),
             f_r=np.asarray(f_r, dtype=np.float32))
    os.replace(tmp, path)
    return path
