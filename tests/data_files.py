"""Helpers for the reader tests: where the shared data live, and small files written from scratch.

The tensor_file writer here is independent of the reader in ``neuenh.data.rgl`` (it follows
the container layout in ``../shared/data/README.md``), so reader and writer check each other.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np
import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
RGL_DIR = SHARED_DATA / "rgl"
RGL_REFERENCE = RGL_DIR / "reference_values.npz"
NBRDF_WEIGHTS = SHARED_DATA / "merl_nbrdf" / "merl_nbrdf_weights.npz"
RGL_MATERIALS = ("paper_white_rgb", "acrylic_felt_green_rgb", "colodur_napoli_4f_rgb", "ilm_solo_m_68_rgb",
                 "irid_flake_paint1_rgb", "aurora_white_rgb", "chm_orange_rgb", "vch_silk_blue_rgb")


def shared(path: Path) -> Path:
    """``path`` inside ../shared/data, or skip the test with the reason."""
    if not path.exists():
        pytest.skip(f"shared data not available: {path} is missing (the real-data files live in ../shared/data)")
    return path


# -- tensor_file, written independently ------------------------------------------------------
TENSOR_DTYPES = {np.dtype(k): code for code, k in enumerate(
    ["u1", "i1", "u2", "i2", "u4", "i4", "u8", "i8", "f2", "f4", "f8"], start=1)}


def tensor_file_bytes(fields: dict[str, np.ndarray], align: int = 8, overrides=None) -> bytes:
    """A "tensor_file" v1.0 holding ``fields`` (C order, data after the header, aligned).

    ``overrides`` {name: {"offset": ..., "shape": ..., "code": ...}} writes other header values
    than the data have, to make broken files."""
    overrides = overrides or {}
    entries = []
    for name, a in fields.items():
        raw = name.encode()
        entries.append((name, raw, np.ascontiguousarray(a)))
    header_len = 12 + 2 + 4 + sum(
        2 + len(raw) + 2 + 1 + 8 + 8 * len(overrides.get(name, {}).get("shape", a.shape)) for name, raw, a in entries)
    offset = math.ceil(header_len / align) * align
    header = b"tensor_file\0" + struct.pack("<BBI", 1, 0, len(entries))
    body = b""
    for name, raw, a in entries:
        o = overrides.get(name, {})
        code = o.get("code", TENSOR_DTYPES[a.dtype.newbyteorder("=")])
        shape = o.get("shape", a.shape)
        header += struct.pack("<H", len(raw)) + raw
        header += struct.pack("<HBQ", len(shape), code, o.get("offset", offset + len(body)))
        header += struct.pack(f"<{len(shape)}Q", *shape)
        body += a.astype(a.dtype.newbyteorder("<")).tobytes()
        body += b"\0" * (-len(body) % align)
    return header + b"\0" * (offset - len(header)) + body


def aliased_tensor_file_bytes(n_fields: int, block_bytes: int) -> bytes:
    """A tensor_file of ONE data block of ``block_bytes`` whose ``n_fields`` fields (u8 vectors) all
    name it: the header of an attack that would make every field a copy of the block."""
    header = b"tensor_file\0" + struct.pack("<BBI", 1, 0, n_fields)
    names = [f"f{i}".encode() for i in range(n_fields)]
    header_len = len(header) + sum(2 + len(n) + 2 + 1 + 8 + 8 for n in names)
    for name in names:
        header += struct.pack("<H", len(name)) + name + struct.pack("<HBQQ", 1, 1, header_len, block_bytes)
    return header + bytes(block_bytes)


def write_tensor_file(path: Path, fields: dict[str, np.ndarray]) -> Path:
    path.write_bytes(tensor_file_bytes(fields))
    return path


def tiny_rgl_fields(vndf=None, rgb=None, n_theta: int = 3, vndf_shape=(4, 5), n: int = 4,
                    ndf: float = 2.0, sigma: float = 0.5) -> dict[str, np.ndarray]:
    """A small, valid isotropic RGL BSDF. ``vndf(x, y)`` and ``rgb(c, x, y)`` give the grids as
    functions of the unit-square coordinates (x = columns, y = rows); defaults: uniform VNDF and
    rgb = (0.1 + x, 0.2 + y, 0.3 + x y / 2); constant ndf and sigma."""
    vndf = vndf or (lambda x, y: np.ones_like(x))
    rgb = rgb or (lambda c, x, y: (0.1 + x, 0.2 + y, 0.3 + 0.5 * x * y)[c])
    h, w = vndf_shape
    vy, vx = np.meshgrid(np.linspace(0, 1, h), np.linspace(0, 1, w), indexing="ij")
    ry, rx = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    theta_i = np.linspace(0.0, 1.5, n_theta).astype(np.float32)
    f32 = np.float32
    return {
        "version": np.array([1, 0], dtype=np.uint32),
        "description": np.frombuffer(b"tiny test material", dtype=np.uint8).copy(),
        "phi_i": np.zeros(1, dtype=f32),
        "theta_i": theta_i,
        "sigma": np.full((2, 6), sigma, dtype=f32),
        "ndf": np.full((2, 6), ndf, dtype=f32),
        "vndf": np.broadcast_to(vndf(vx, vy), (1, n_theta, h, w)).astype(f32),
        "luminance": np.ones((1, n_theta, n, n), dtype=f32),
        "rgb": np.broadcast_to(np.stack([rgb(c, rx, ry) for c in range(3)]), (1, n_theta, 3, n, n)).astype(f32),
        "jacobian": np.ones(1, dtype=np.uint8),
        "valid": np.ones(n * n, dtype=np.uint8),
    }


# -- other small sources ---------------------------------------------------------------------
def lambertian(rho=(0.2, 0.5, 0.8)):
    rho = torch.tensor(rho, dtype=torch.float64) / math.pi

    def f(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        return rho.expand(len(wi), 3).clone()

    return f


def nbrdf_weights(names, seed: int = 0, hidden: int = 5) -> dict[str, np.ndarray]:
    """Random small NBRDF networks (6-hidden-hidden-3), in the weights file's layout."""
    rng = np.random.default_rng(seed)
    arrays: dict[str, np.ndarray] = {"names": np.array(names)}
    for name in names:
        for key, shape in (("W1", (6, hidden)), ("b1", (hidden,)), ("W2", (hidden, hidden)), ("b2", (hidden,)),
                           ("W3", (hidden, 3)), ("b3", (3,))):
            arrays[f"{name}/{key}"] = (0.5 * rng.standard_normal(shape)).astype(np.float32)
    return arrays


def hemisphere(n: int, seed: int, min_z: float = 0.0) -> np.ndarray:
    """``n`` directions uniform on the upper hemisphere with z > ``min_z``."""
    rng = np.random.default_rng(seed)
    z = min_z + (1 - min_z) * rng.random(n)
    phi = 2 * math.pi * rng.random(n)
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
