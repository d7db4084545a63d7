"""EPFL RGL measured BRDFs: the "tensor_file" container and the evaluator of its data.

Dupuy & Jakob 2018, "An adaptive parameterization for efficient material acquisition and
representation" (ACM TOG 37(6)). Each material is stored as tensors in a small binary container
("tensor_file" v1.0, little-endian): the 12 bytes ``b"tensor_file\\0"``, the version (u8 major 1,
u8 minor 0), a u32 field count, then per field its name (u16 length + bytes), u16 ndim, u8 dtype
code, u64 absolute byte offset of its C-order data and ndim × u64 shape.

Evaluation follows the reference implementation (powitacq, rgl-epfl/brdf-loader) step by step, in
float32 arithmetic like it, vectorised over pairs:

1. ``wm = normalize(wi + wo)``; spherical angles of ``wi`` and ``wm``; angles map to the unit
   square by ``u(theta) = sqrt(2 theta / pi)`` and ``u(phi) = (phi + pi) / (2 pi)`` (isotropic
   data use ``phi_m - phi_i``, wrapped into [0, 1)).
2. The "VNDF" warp is a bilinear 2-D density on the unit square, conditioned (multilinearly) on
   ``phi_i, theta_i``; inverting its marginal/conditional CDFs at ``u_wm`` gives the point of the
   sample space where the spectral data were measured.
3. ``rgb`` is interpolated bilinearly there (per channel, conditioned on ``phi_i, theta_i``) and
   clipped at 0, then multiplied by ``ndf(u_wm) / (4 sigma(u_wi))``.

The result is **f_r · cos(theta_o)** (what ``RGLMaterial.evaluate_cos`` returns); the project's
convention is f_r without the cosine, so ``RGLMaterial.evaluate`` divides by ``wo.z``. Both are
exactly 0 when ``wi.z <= 0`` or ``wo.z <= 0``.

Every problem with a file is a ``TensorFileError`` (a ``DataError``) naming the file.
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from .errors import DataError, read_bytes
from .directions import Sampling

MAGIC = b"tensor_file\x00"
VERSION = (1, 0)

#: dtype codes of the container (little-endian); 0 is "invalid".
DTYPES: dict[int, np.dtype] = {
    1: np.dtype("<u1"), 2: np.dtype("<i1"), 3: np.dtype("<u2"), 4: np.dtype("<i2"),
    5: np.dtype("<u4"), 6: np.dtype("<i4"), 7: np.dtype("<u8"), 8: np.dtype("<i8"),
    9: np.dtype("<f2"), 10: np.dtype("<f4"), 11: np.dtype("<f8"),
}

_F32 = np.float32
_PI = _F32(math.pi)
_CHUNK = 1 << 16  # pairs per vectorised batch: keeps the temporaries in cache-friendly sizes


class TensorFileError(DataError):
    """A tensor_file (RGL ``.bsdf``) that cannot be read or evaluated."""


# -- the container ---------------------------------------------------------------------------
def is_tensor_file(head: bytes) -> bool:
    """Whether ``head`` (the first bytes of a file) starts like a tensor_file."""
    return head[: len(MAGIC)] == MAGIC


def parse_tensor_file(content: bytes, path: str | os.PathLike = "<bytes>") -> dict[str, np.ndarray]:
    """All fields of a tensor_file held in ``content``, by name, as (copied) numpy arrays."""

    def fail(msg: str) -> TensorFileError:
        return TensorFileError(f"{path}: {msg}")

    size = len(content)
    if size < len(MAGIC) + 6:
        raise fail(f"too short for a tensor_file header ({size} bytes)")
    if content[: len(MAGIC)] != MAGIC:
        raise fail(f"not a tensor_file (bad magic {content[:len(MAGIC)]!r}, expected {MAGIC!r})")
    major, minor, n_fields = struct.unpack_from("<BBI", content, len(MAGIC))
    if (major, minor) != VERSION:
        raise fail(f"unsupported tensor_file version {major}.{minor} (expected 1.0)")
    pos = len(MAGIC) + 6
    # The smallest field entry is 2 (name length) + 2 (ndim) + 1 (dtype) + 8 (offset) = 13 bytes.
    if n_fields * 13 > size - pos:
        raise fail(f"header claims {n_fields} fields, more than a file of {size} bytes can describe")

    def take(fmt: str, what: str) -> tuple:
        nonlocal pos
        width = struct.calcsize(fmt)
        if pos + width > size:
            raise fail(f"header truncated while reading {what} (needs byte {pos + width}, file has {size})")
        values = struct.unpack_from(fmt, content, pos)
        pos += width
        return values

    entries: dict[str, tuple[np.dtype, int, tuple[int, ...], int]] = {}  # dtype, offset, shape, bytes
    for i in range(n_fields):
        where = f"field {i + 1} of {n_fields}"
        (name_len,) = take("<H", f"the name length of {where}")
        (raw_name,) = take(f"<{name_len}s", f"the name of {where}")
        try:
            name = raw_name.decode("utf-8")
        except UnicodeDecodeError:
            raise fail(f"the name of {where} is not UTF-8 ({raw_name!r})") from None
        where = f"field {name!r}"
        ndim, code, offset = take("<HBQ", f"the ndim, dtype and offset of {where}")
        shape = take(f"<{ndim}Q", f"the shape of {where}")
        if ndim > 32:  # numpy's array rank limit (32 in numpy 1, 64 in numpy 2)
            raise fail(f"{where} has {ndim} dimensions (at most 32 are supported)")
        if code not in DTYPES:
            raise fail(f"{where} has unknown dtype code {code} (valid: 1..11)")
        if math.prod(d for d in shape if d) * DTYPES[code].itemsize > size:
            # Even an empty field (a zero in its shape) cannot have other extents beyond the file.
            raise fail(f"{where} has shape {list(shape)}, larger than the whole file ({size} bytes)")
        if name in entries:
            raise fail(f"{where} appears twice")
        entries[name] = (DTYPES[code], offset, shape, math.prod(shape) * DTYPES[code].itemsize)
    _check_layout(entries, pos, size, fail)
    # The data, once the whole header is known to be sound: every field its own bytes, so the copies
    # together hold at most the file's size.
    fields: dict[str, np.ndarray] = {}
    for name, (dtype, offset, shape, _) in entries.items():
        data = np.frombuffer(content, dtype=dtype, count=math.prod(shape), offset=offset).reshape(shape)
        fields[name] = data.astype(dtype.newbyteorder("="))  # a native-order copy
    return fields


def _check_layout(entries: dict[str, tuple[np.dtype, int, tuple[int, ...], int]], header_end: int, size: int,
                  fail) -> None:
    """Each field's bytes lie inside the file after the header, apart from every other field's: a
    header whose fields all name one block (or overlap) would make every field a copy of it, swelling
    a small file to any size in memory, so it is refused before anything is copied."""
    for name, (dtype, offset, shape, nbytes) in entries.items():
        if offset > size or nbytes > size - offset:
            raise fail(f"field {name!r} ({dtype.name}{list(shape)}, {nbytes} bytes at offset {offset}) "
                       f"extends past the end of the file ({size} bytes)")
    total = sum(nbytes for *_, nbytes in entries.values())
    if total > size - header_end:
        raise fail(f"its fields claim {total} bytes in all, more than the {size - header_end} bytes after its "
                   "header: fields overlap")
    spans = sorted((offset, offset + nbytes, name) for name, (_, offset, _, nbytes) in entries.items() if nbytes)
    if spans and spans[0][0] < header_end:
        start, _, name = spans[0]
        raise fail(f"field {name!r} starts at byte {start}, inside the header (which ends at byte {header_end})")
    for (_, end, first), (start, _, second) in zip(spans, spans[1:]):
        if start < end:
            raise fail(f"fields {first!r} and {second!r} overlap (bytes {start}..{end - 1} belong to both)")


def read_tensor_file(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """All fields of the tensor_file at ``path``; any problem is a ``TensorFileError``."""
    return parse_tensor_file(read_bytes(path, TensorFileError), path)


# -- the reference's piecewise-bilinear warp ---------------------------------------------------
class _Params:
    """Interval indices and linear weights of the conditioning parameters of a batch."""

    def __init__(self, values: list[np.ndarray], params: list[np.ndarray]):
        self.index: list[np.ndarray | None] = []
        self.w0: list[np.ndarray | None] = []
        self.w1: list[np.ndarray | None] = []
        for grid, x in zip(values, params):
            if len(grid) == 1:  # a parameter discretised once: weight 1 on its only slice
                self.index.append(None)
                self.w0.append(None)
                self.w1.append(None)
                continue
            # The largest i with grid[i] <= x, clamped to [0, len - 2] (powitacq's find_interval).
            i = np.clip(np.searchsorted(grid, x, side="right") - 1, 0, len(grid) - 2)
            p0, p1 = grid[i], grid[i + 1]
            w1 = np.clip((x - p0) / (p1 - p0), _F32(0), _F32(1)).astype(_F32)
            self.index.append(i)
            self.w0.append(_F32(1) - w1)
            self.w1.append(w1)


class _Warp2D:
    """Marginal2D of powitacq/Mitsuba: a bilinear density on [0, 1]² given by an (H, W) grid per
    parameter slice (grid ``[..., H, W]``, x = columns, y = rows), interpolated multilinearly in
    the parameters; with ``build_cdf`` it is normalised and carries the marginal (rows) and
    conditional (columns) CDFs that ``invert`` needs, else ``eval`` returns the data unchanged."""

    def __init__(self, grid: np.ndarray, param_values: list[np.ndarray], build_cdf: bool):
        n_params = len(param_values)
        self.param_size = [len(v) for v in param_values]
        self.param_values = [np.asarray(v, dtype=_F32) for v in param_values]
        self.h, self.w = grid.shape[-2:]
        self.inv_x, self.inv_y = _F32(self.w - 1), _F32(self.h - 1)
        self.hprod = self.inv_x * self.inv_y
        # Strides between slices per parameter (0 for a parameter of resolution 1).
        self.strides = [0] * n_params
        slices = 1
        for d in reversed(range(n_params)):
            self.strides[d] = slices if self.param_size[d] > 1 else 0
            slices *= self.param_size[d]
        data = np.asarray(grid, dtype=_F32).reshape(slices, self.h, self.w)
        self.slice_size = self.h * self.w
        if build_cdf:
            # Conditional CDF along each row, marginal CDF over rows: trapezoids summed in float64.
            cond = np.zeros_like(data)
            cond[:, :, 1:] = np.cumsum(0.5 * (data[:, :, :-1].astype(np.float64) + data[:, :, 1:]), axis=2)
            row_mass = cond[:, :, -1].astype(np.float64)
            marg = np.zeros((slices, self.h), dtype=_F32)
            marg[:, 1:] = np.cumsum(0.5 * (row_mass[:, :-1] + row_mass[:, 1:]), axis=1)
            with np.errstate(divide="ignore"):
                norm = (_F32(1) / marg[:, -1]).astype(_F32)
            self.cond = (cond * norm[:, None, None]).reshape(-1)
            self.marg = (marg * norm[:, None]).reshape(-1)
            self.data = (data * norm[:, None, None]).reshape(-1)
        else:
            self.data = (data * (_F32(1) / self.hprod)).reshape(-1)

    def params(self, params: list[np.ndarray]) -> _Params:
        return _Params(self.param_values, params)

    def _slice_offset(self, p: _Params) -> np.ndarray | int:
        offset = 0
        for d, i in enumerate(p.index):
            if i is not None:
                offset = offset + self.strides[d] * i
        return offset

    def _lookup(self, table: np.ndarray, i0, p: _Params, size: int, level: int | None = None):
        """Multilinear interpolation over the parameters of ``table[i0]`` (powitacq's lookup)."""
        level = len(p.index) if level is None else level
        if level == 0:
            return table[i0]
        d = level - 1
        v0 = self._lookup(table, i0, p, size, d)
        if p.index[d] is None:
            return v0
        v1 = self._lookup(table, i0 + self.strides[d] * size, p, size, d)
        return v0 * p.w0[d] + v1 * p.w1[d]

    def _patch(self, x: np.ndarray, y: np.ndarray):
        """Scale to patch units; the patch index (clamped) and the position inside it."""
        px, py = x * self.inv_x, y * self.inv_y
        ix = np.clip(np.floor(np.nan_to_num(px)), 0, self.w - 2).astype(np.int64)
        iy = np.clip(np.floor(np.nan_to_num(py)), 0, self.h - 2).astype(np.int64)
        return ix, iy, (px - ix).astype(_F32), (py - iy).astype(_F32)

    def eval(self, x: np.ndarray, y: np.ndarray, p: _Params) -> np.ndarray:
        """The interpolated value at (x, y) in [0, 1]²."""
        ix, iy, w1x, w1y = self._patch(x, y)
        w0x, w0y = _F32(1) - w1x, _F32(1) - w1y
        index = ix + iy * self.w + self._slice_offset(p) * self.slice_size
        s = self.slice_size
        v00 = self._lookup(self.data, index, p, s)
        v10 = self._lookup(self.data, index + 1, p, s)
        v01 = self._lookup(self.data, index + self.w, p, s)
        v11 = self._lookup(self.data, index + self.w + 1, p, s)
        return (w0y * (w0x * v00 + w1x * v10) + w1y * (w0x * v01 + w1x * v11)) * self.hprod

    def invert(self, x: np.ndarray, y: np.ndarray, p: _Params) -> tuple[np.ndarray, np.ndarray]:
        """The sample-space point that the warp maps to (x, y): the CDFs evaluated there."""
        ix, iy, sx, sy = self._patch(x, y)
        slice_offset = self._slice_offset(p)
        s = self.slice_size
        index = ix + iy * self.w + slice_offset * s
        v00 = self._lookup(self.data, index, p, s)
        v10 = self._lookup(self.data, index + 1, p, s)
        v01 = self._lookup(self.data, index + self.w, p, s)
        v11 = self._lookup(self.data, index + self.w + 1, p, s)
        w0y = _F32(1) - sy
        c0 = w0y * v00 + sy * v01
        c1 = w0y * v10 + sy * v11
        # x: the integral of the interpolated row density up to sx, plus the CDF at the patch start,
        # divided by the interpolated row total.
        sx = sx * (c0 + _F32(0.5) * sx * (c1 - c0))
        cdf0 = self._lookup(self.cond, index, p, s)
        cdf1 = self._lookup(self.cond, index + self.w, p, s)
        sx = sx + (w0y * cdf0 + sy * cdf1)
        row = iy * self.w + slice_offset * s
        r0 = self._lookup(self.cond, row + (self.w - 1), p, s)
        r1 = self._lookup(self.cond, row + (2 * self.w - 1), p, s)
        with np.errstate(divide="ignore", invalid="ignore"):
            sx = sx / (w0y * r0 + sy * r1)
        # y: the same along the marginal.
        sy = sy * (r0 + _F32(0.5) * sy * (r1 - r0))
        sy = sy + self._lookup(self.marg, iy + slice_offset * self.h, p, self.h)
        return sx.astype(_F32), sy.astype(_F32)


def _elevation(d: np.ndarray) -> np.ndarray:
    """acos(d.z), evaluated as 2 asin(|d - z| / 2): accurate near the pole, where the warp's
    sqrt(theta) parameterisation is most sensitive (the reference does the same)."""
    dz = d[:, 2] - _F32(1)
    return _F32(2) * np.arcsin(_F32(0.5) * np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + dz * dz))


def _theta2u(theta: np.ndarray) -> np.ndarray:
    return np.sqrt(theta * (_F32(2) / _PI))


def _phi2u(phi: np.ndarray) -> np.ndarray:
    return (phi + _PI) / (_F32(2) * _PI)


# -- the material ----------------------------------------------------------------------------
_REQUIRED = {  # name: (dtype, ndim), what powitacq requires of a file
    "description": (np.uint8, 1), "jacobian": (np.uint8, 1), "theta_i": (np.float32, 1),
    "phi_i": (np.float32, 1), "ndf": (np.float32, 2), "sigma": (np.float32, 2),
    "vndf": (np.float32, 4), "luminance": (np.float32, 4), "rgb": (np.float32, 5),
}


def _validate(fields: dict[str, np.ndarray], path) -> None:
    def fail(msg: str) -> TensorFileError:
        return TensorFileError(f"{path}: {msg}")

    missing = [k for k in _REQUIRED if k not in fields]
    if missing:
        raise fail(f"not an RGL BSDF: missing field(s) {missing}")
    for name, (dtype, ndim) in _REQUIRED.items():
        a = fields[name]
        if a.dtype != np.dtype(dtype) or a.ndim != ndim:
            raise fail(f"field {name!r} must be {np.dtype(dtype).name} with {ndim} dimension(s), "
                       f"got {a.dtype.name}{list(a.shape)}")
    n_phi, n_theta = len(fields["phi_i"]), len(fields["theta_i"])
    if n_phi < 1 or n_theta < 1:
        raise fail(f"phi_i and theta_i must not be empty, got {n_phi} and {n_theta} values")
    if fields["jacobian"].shape != (1,):
        raise fail(f"field 'jacobian' must hold one value, got shape {list(fields['jacobian'].shape)}")
    vndf, lum, rgb = fields["vndf"], fields["luminance"], fields["rgb"]
    if vndf.shape[:2] != (n_phi, n_theta):
        raise fail(f"vndf must have shape [{n_phi}, {n_theta}, H, W] (phi_i, theta_i), got {list(vndf.shape)}")
    if lum.shape[:2] != (n_phi, n_theta) or lum.shape[2] != lum.shape[3]:
        raise fail(f"luminance must have shape [{n_phi}, {n_theta}, N, N], got {list(lum.shape)}")
    if rgb.shape != (n_phi, n_theta, 3) + lum.shape[2:]:
        raise fail(f"rgb must have shape {[n_phi, n_theta, 3, *lum.shape[2:]]}, got {list(rgb.shape)}")
    for name in ("ndf", "sigma", "vndf", "rgb"):
        if min(fields[name].shape[-2:]) < 2:
            raise fail(f"field {name!r} needs at least a 2 x 2 grid, got {list(fields[name].shape)}")
    for name in ("theta_i", "phi_i", "ndf", "sigma", "vndf", "rgb"):
        bad = ~np.isfinite(fields[name])
        if bad.any():
            raise fail(f"field {name!r} has {int(bad.sum())} non-finite value(s)")
    for name in ("theta_i", "phi_i"):
        if (np.diff(fields[name]) <= 0).any():
            raise fail(f"field {name!r} must be strictly increasing, got {fields[name].tolist()}")
    if (vndf < 0).any():
        raise fail("field 'vndf' has negative values (it is a density)")
    rows = vndf.reshape(-1, *vndf.shape[2:]).sum(axis=(1, 2), dtype=np.float64)
    if (rows <= 0).any():
        raise fail(f"field 'vndf' has {int((rows <= 0).sum())} slice(s) that integrate to zero")
    if n_phi > 2:
        phi = fields["phi_i"]
        reduction = round(2 * math.pi / float(phi[-1] - phi[0]))
        if reduction != 1:
            raise fail(f"anisotropic data with symmetry reduction {reduction} is not supported "
                       "(phi_i must span the full circle)")


@dataclass
class RGLMaterial:
    """A measured RGL material: continuous, evaluated like the reference (powitacq).

    ``evaluate(wi, wo)`` -> f_r (n, 3) float64 without the cosine; ``evaluate_cos`` -> the
    reference's f_r·cos(theta_o) as float32 numpy; ``samples(n, seed)`` -> Rusinkiewicz-uniform
    pairs and their f_r (phi_h = 0 for isotropic data).
    """

    name: str
    isotropic: bool
    metadata: dict = field(default_factory=dict)
    fields: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        f = self.fields
        params = [f["phi_i"], f["theta_i"]]
        with np.errstate(all="ignore"):  # extreme data: checked by ``finite`` (rgl_from_fields)
            self._ndf = _Warp2D(f["ndf"], [], build_cdf=False)
            self._sigma = _Warp2D(f["sigma"], [], build_cdf=False)
            self._vndf = _Warp2D(f["vndf"], params, build_cdf=True)
            self._rgb = [_Warp2D(f["rgb"][:, :, c], params, build_cdf=False) for c in range(3)]

    @property
    def finite(self) -> bool:
        """Whether the normalised VNDF and its CDFs are finite in float32 (data neither too small
        nor too large to normalise)."""
        v = self._vndf
        return bool(np.isfinite(v.data).all() and np.isfinite(v.cond).all() and np.isfinite(v.marg).all())

    def evaluate_cos(self, wi, wo) -> np.ndarray:
        """f_r · cos(theta_o) (n, 3) float32: what the reference evaluator returns, computed the same
        way (float32 steps; differences are float32 rounding, ~1e-7 relative in the median)."""
        wi, wo = _directions(wi, wo)
        out = np.zeros((len(wi), 3), dtype=_F32)
        for start in range(0, len(wi), _CHUNK):
            stop = start + _CHUNK
            out[start:stop] = self._eval_chunk(wi[start:stop], wo[start:stop])
        return out

    def evaluate(self, wi, wo) -> torch.Tensor:
        """f_r (n, 3) float64 without the cosine factor; 0 where either direction is not above."""
        wi32, wo32 = _directions(wi, wo)
        value = torch.from_numpy(self.evaluate_cos(wi32, wo32)).to(torch.float64)
        above = torch.from_numpy((wi32[:, 2:3] > 0) & (wo32[:, 2:3] > 0))
        cos_o = torch.as_tensor(wo).detach().to("cpu", torch.float64)[:, 2:3]
        return torch.where(above, value / torch.where(above, cos_o, torch.ones_like(cos_o)), torch.zeros_like(value))

    def samples(self, n: int, seed: int, sampling: Sampling = Sampling()
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        wi, wo = sampling.directions(n, seed, self.isotropic)
        return wi, wo, self.evaluate(wi, wo)

    def _eval_chunk(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):  # degenerate data may overflow; such values end up 0
            return self._eval_chunk_unchecked(wi, wo)

    def _eval_chunk_unchecked(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        out = np.zeros((len(wi), 3), dtype=_F32)
        if not above.all():
            wi, wo = wi[above], wo[above]
        if len(wi) == 0:
            return out
        m = wi + wo
        m = m / np.sqrt(m[:, 0] * m[:, 0] + m[:, 1] * m[:, 1] + m[:, 2] * m[:, 2])[:, None]
        theta_i, theta_m = _elevation(wi), _elevation(m)
        phi_i = np.arctan2(wi[:, 1], wi[:, 0])
        phi_m = np.arctan2(m[:, 1], m[:, 0])
        out[above] = self._eval_angles(theta_i, phi_i, theta_m, phi_m)
        return out

    def _eval_angles(self, theta_i, phi_i, theta_m, phi_m) -> np.ndarray:
        ui_x, ui_y = _theta2u(theta_i), _phi2u(phi_i)
        um_x = _theta2u(theta_m)
        um_y = _phi2u(phi_m - phi_i if self.isotropic else phi_m)
        um_y = um_y - np.floor(um_y)
        p = self._vndf.params([phi_i, theta_i])
        sx, sy = self._vndf.invert(um_x, um_y, p)
        scale = self._ndf.eval(um_x, um_y, _NO_PARAMS) / (_F32(4) * self._sigma.eval(ui_x, ui_y, _NO_PARAMS))
        value = np.stack([np.maximum(_F32(0), rgb.eval(sx, sy, p)) * scale for rgb in self._rgb], axis=1)
        return np.nan_to_num(value, nan=0.0, posinf=0.0, neginf=0.0)


_NO_PARAMS = _Params([], [])


def _directions(wi, wo) -> tuple[np.ndarray, np.ndarray]:
    arrays = []
    for label, v in (("wi", wi), ("wo", wo)):
        if isinstance(v, torch.Tensor):
            v = v.detach().cpu().numpy()
        v = np.asarray(v, dtype=_F32)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"{label} must have shape (n, 3), got {v.shape}")
        arrays.append(v)
    if arrays[0].shape != arrays[1].shape:
        raise ValueError(f"wi and wo must have the same shape, got {arrays[0].shape} and {arrays[1].shape}")
    return arrays[0], arrays[1]


def rgl_from_fields(fields: dict[str, np.ndarray], path: str | os.PathLike = "<fields>",
                    name: str | None = None) -> RGLMaterial:
    """An ``RGLMaterial`` from already parsed tensor_file fields (validated)."""
    with np.errstate(all="ignore"):  # differences of extreme values: the checks still hold
        _validate(fields, path)
    description = bytes(fields["description"]).decode("utf-8", errors="replace").rstrip("\0")
    n_phi = len(fields["phi_i"])
    metadata = {
        "source": "rgl",
        "path": str(path),
        "description": description,
        "jacobian": bool(fields["jacobian"][0]),
        "theta_i": fields["theta_i"].tolist(),
        "phi_i": fields["phi_i"].tolist(),
        "vndf_resolution": list(fields["vndf"].shape[2:]),
        "rgb_resolution": list(fields["rgb"].shape[3:]),
        "returns": "evaluate: f_r (no cosine); evaluate_cos: f_r * cos(theta_o) as the reference",
    }
    if "version" in fields:
        metadata["version"] = fields["version"].tolist()
    material = RGLMaterial(name or Path(path).stem, isotropic=n_phi <= 2, metadata=metadata, fields=fields)
    if not material.finite:
        raise TensorFileError(f"{path}: field 'vndf' cannot be normalised in float32 (values too small or too large)")
    return material


def load_rgl(path: str | os.PathLike, name: str | None = None) -> RGLMaterial:
    """Read the RGL ``.bsdf`` at ``path``; ``name`` defaults to the file's stem."""
    return rgl_from_fields(read_tensor_file(path), path, name)
