"""MERL BRDF tables (Matusik, Pfister, Brand, McMillan 2003, "A Data-Driven Reflectance Model"):
read, evaluate, and write.

**Format** (``.binary``, little-endian): three int32 ``(90, 90, 180)``, then 3 × 1,458,000 float64,
channel-major R, G, B, each ``[theta_h, theta_d, phi_d]`` in C order. Stored values are scaled:
f_r = stored × (1/1500, 1.15/1500, 1.66/1500) for R, G, B. A negative stored value marks an
invalid (unmeasured) bin.

**Bins** of the Rusinkiewicz angles (Rusinkiewicz 1998; ``phi_h`` unused, MERL is isotropic):
``i_theta_h = int(sqrt(theta_h / (pi/2)) * 90)``, ``i_theta_d = int(theta_d / (pi/2) * 90)`` and
``i_phi_d = int(phi_d / pi * 180)``, each clamped into range, after folding ``phi_d`` into
[0, pi) by reciprocity (+pi when negative, -pi when >= pi). Swapping ``wi`` and ``wo`` turns
``phi_d`` into ``phi_d ± pi``, so the fold is exactly reciprocity; readers that skip it send
``phi_d`` in (pi, 2 pi) to the clamped last bin (or blend bins 179 and 0).

**Evaluation** is the standard nearest-bin lookup of the MERL reference code (``BRDFRead.cpp``):
the value of the bin the pair falls into, no interpolation. **Invalid bins** (negative stored
values) are not measurements: ``evaluate`` returns 0 there (as renderers that clamp MERL values
at 0 do), ``valid`` tells which pairs fall into a valid bin, and ``samples`` draws only from
valid bins. Pairs with ``wi.z <= 0`` or ``wo.z <= 0`` evaluate to 0.

**Writing** (``write_merl``) tabulates any BRDF at the bin centres — ``theta_h`` at
``((i + 0.5) / 90)² pi/2``, ``theta_d`` at ``(j + 0.5) / 90 · pi/2``, ``phi_d`` at
``(k + 0.5) / 180 · pi``, with ``phi_h = 0`` — so analytical, enhanced or NBRDF models can be
exported as MERL tables. Bins whose centre has a direction at or below the horizon are written
as invalid (-1).
"""

from __future__ import annotations

import math
import os
import struct
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ..files import atomic_write
from .errors import DataError, read_bytes
from .directions import Sampling, from_rusinkiewicz, to_rusinkiewicz

N_THETA_H, N_THETA_D, N_PHI_D = 90, 90, 180
DIMS = (N_THETA_H, N_THETA_D, N_PHI_D)
N_BINS = N_THETA_H * N_THETA_D * N_PHI_D  # 1,458,000
HEADER = struct.pack("<3i", *DIMS)
FILE_SIZE = len(HEADER) + 3 * N_BINS * 8
SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
INVALID = -1.0  # what write_merl stores in a bin it cannot measure

Evaluate = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


class MERLError(DataError):
    """A MERL ``.binary`` file that cannot be read."""


# -- bins ------------------------------------------------------------------------------------
def fold_phi_d(phi_d: np.ndarray) -> np.ndarray:
    """``phi_d`` folded into [0, pi) by reciprocity (f(phi_d) = f(phi_d + pi))."""
    phi_d = np.asarray(phi_d, dtype=np.float64)
    phi_d = np.where(phi_d < 0, phi_d + math.pi, phi_d)
    return np.where(phi_d >= math.pi, phi_d - math.pi, phi_d)


def bin_indices(theta_h, theta_d, phi_d) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (theta_h, theta_d, phi_d) bin of Rusinkiewicz angles (radians, any phi_d)."""
    theta_h = np.nan_to_num(np.asarray(theta_h, dtype=np.float64))
    theta_d = np.nan_to_num(np.asarray(theta_d, dtype=np.float64))
    phi_d = fold_phi_d(np.nan_to_num(np.asarray(phi_d, dtype=np.float64)))
    i_h = np.sqrt(np.clip(theta_h, 0.0, None) / (math.pi / 2)) * N_THETA_H
    i_d = theta_d / (math.pi / 2) * N_THETA_D
    i_p = phi_d / math.pi * N_PHI_D
    # int() truncates toward zero; every argument is >= 0 here, so floor is the same.
    return (np.clip(np.floor(i_h), 0, N_THETA_H - 1).astype(np.int64),
            np.clip(np.floor(i_d), 0, N_THETA_D - 1).astype(np.int64),
            np.clip(np.floor(i_p), 0, N_PHI_D - 1).astype(np.int64))


def flat_index(theta_h, theta_d, phi_d) -> np.ndarray:
    """Index into one channel's 1,458,000 values of the bin of these angles."""
    i_h, i_d, i_p = bin_indices(theta_h, theta_d, phi_d)
    return (i_h * N_THETA_D + i_d) * N_PHI_D + i_p


def direction_bins(wi, wo) -> np.ndarray:
    """Flat bin index of each direction pair (n, 3) in the local frame."""
    wi, wo = as_directions(wi, wo)
    theta_h, _, theta_d, phi_d = to_rusinkiewicz(wi, wo)
    return flat_index(theta_h.numpy(), theta_d.numpy(), phi_d.numpy())


def bin_centres() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rusinkiewicz angles (theta_h, theta_d, phi_d) of the bin centres, each ``DIMS``-shaped."""
    u_h = (np.arange(N_THETA_H) + 0.5) / N_THETA_H
    theta_h = u_h * u_h * (math.pi / 2)
    theta_d = (np.arange(N_THETA_D) + 0.5) / N_THETA_D * (math.pi / 2)
    phi_d = (np.arange(N_PHI_D) + 0.5) / N_PHI_D * math.pi
    return tuple(np.meshgrid(theta_h, theta_d, phi_d, indexing="ij"))


def bin_centre_directions(start: int = 0, stop: int = N_BINS) -> tuple[torch.Tensor, torch.Tensor]:
    """``wi, wo`` (float64, phi_h = 0) at the centres of flat bins ``start:stop``."""
    index = np.arange(start, stop)
    i_h, rest = np.divmod(index, N_THETA_D * N_PHI_D)
    i_d, i_p = np.divmod(rest, N_PHI_D)
    u_h = (i_h + 0.5) / N_THETA_H
    angles = [u_h * u_h * (math.pi / 2), (i_d + 0.5) / N_THETA_D * (math.pi / 2), (i_p + 0.5) / N_PHI_D * math.pi]
    theta_h, theta_d, phi_d = (torch.from_numpy(a) for a in angles)
    return from_rusinkiewicz(theta_h, torch.zeros_like(theta_h), theta_d, phi_d)


# -- reading ---------------------------------------------------------------------------------
def looks_like_merl(head: bytes, size: int) -> bool:
    """Whether a file starting with ``head`` (>= 12 bytes) of ``size`` bytes is a MERL table:
    the standard dimensions, or three positive int32 whose table fills the file exactly."""
    if len(head) < 12:
        return False
    if head[:12] == HEADER:
        return True
    dims = struct.unpack_from("<3i", head)
    return all(0 < d <= 100_000 for d in dims) and 12 + 24 * math.prod(dims) == size


def parse_merl(content: bytes, path: str | os.PathLike = "<bytes>") -> np.ndarray:
    """The scaled table (3, 90, 90, 180) float64 held in ``content``; negative = invalid."""

    def fail(msg: str) -> MERLError:
        return MERLError(f"{path}: {msg}")

    if len(content) < 12:
        raise fail(f"too short for a MERL header ({len(content)} bytes, needs 12)")
    dims = struct.unpack_from("<3i", content)
    if dims != DIMS:
        raise fail(f"MERL dimensions must be {DIMS} (theta_h, theta_d, phi_d), got {dims}")
    if len(content) != FILE_SIZE:
        what = "truncated" if len(content) < FILE_SIZE else "has trailing bytes"
        raise fail(f"{what}: a MERL table is {FILE_SIZE} bytes (header + 3 x {N_BINS} float64), "
                   f"the file has {len(content)}")
    raw = np.frombuffer(content, dtype="<f8", offset=12).reshape(3, N_BINS)
    scaled = raw * SCALE[:, None]
    # Models compute in float32: a value beyond its range would be inf there (a silently wrong fit).
    for bad, what in ((~np.isfinite(raw), "non-finite value(s)"),
                      (np.abs(scaled) > np.finfo(np.float32).max, "value(s) beyond float32's range (3.4e38)")):
        if bad.any():
            channel, index = (int(v[0]) for v in np.nonzero(bad))
            i_h, i_d, i_p = np.unravel_index(index, DIMS)
            raise fail(f"{int(bad.sum())} {what}, first in channel {'RGB'[channel]} at bin "
                       f"(theta_h {i_h}, theta_d {i_d}, phi_d {i_p})")
    return scaled.reshape(3, *DIMS)


def read_merl(path: str | os.PathLike) -> np.ndarray:
    """The scaled MERL table at ``path`` as (3, 90, 90, 180) float64 f_r; negative = invalid."""
    return parse_merl(read_bytes(path, MERLError), path)


@dataclass
class MERLMaterial:
    """A MERL table as a material: nearest-bin evaluation, isotropic, invalid bins masked out."""

    name: str
    table: np.ndarray = field(repr=False)  # (3, 90, 90, 180) scaled f_r, negative = invalid
    metadata: dict = field(default_factory=dict)
    isotropic: bool = True

    def __post_init__(self) -> None:
        flat = np.ascontiguousarray(self.table, dtype=np.float64).reshape(3, N_BINS)
        self._valid = (flat >= 0).all(axis=0)
        self._values = np.where(self._valid, flat, 0.0).T.copy()  # (N_BINS, 3)

    @property
    def valid_fraction(self) -> float:
        return float(self._valid.mean())

    def valid(self, wi, wo) -> torch.Tensor:
        """Whether each pair is above the horizon and falls into a valid (measured) bin."""
        wi, wo = as_directions(wi, wo)
        above = ((wi[:, 2] > 0) & (wo[:, 2] > 0)).numpy()
        return torch.from_numpy(above & self._valid[direction_bins(wi, wo)])

    def evaluate(self, wi, wo) -> torch.Tensor:
        """f_r (n, 3) float64 of the bin each pair falls into; 0 in invalid bins and below the horizon."""
        wi, wo = as_directions(wi, wo)
        above = ((wi[:, 2] > 0) & (wo[:, 2] > 0)).numpy()
        f = self._values[direction_bins(wi, wo)]
        f[~above] = 0.0
        return torch.from_numpy(f)

    def samples(self, n: int, seed: int, sampling: Sampling = Sampling()
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``n`` pairs drawn as ``sampling`` says (by default Rusinkiewicz-uniform at phi_h = 0)
        that fall into valid bins, and their f_r."""
        if n == 0 or self._valid.all():
            wi, wo = sampling.directions(n, seed, True)
            return wi, wo, self.evaluate(wi, wo)
        if not self._valid.any():
            raise ValueError(f"MERL material {self.name!r} has no valid bin to sample")
        # Valid pairs of each kind apart, so rejecting invalid bins keeps the near-mirror share.
        near = int(round(n * sampling.near_mirror))
        wi, wo = (torch.cat(parts) for parts in zip(
            self._valid_pairs(n - near, seed, replace(sampling, near_mirror=0.0)),
            self._valid_pairs(near, seed ^ 0x4D4952, replace(sampling, near_mirror=1.0))))
        return wi, wo, self.evaluate(wi, wo)

    def _valid_pairs(self, n: int, seed: int, sampling: Sampling) -> tuple[torch.Tensor, torch.Tensor]:
        m = n
        while m < 1024 * n + 10_000_000:  # deterministic in (n, seed): draw more until enough are valid
            m = 2 * m
            wi, wo = sampling.directions(m, seed, True)
            keep = self.valid(wi, wo)
            if int(keep.sum()) >= n:
                return wi[keep][:n], wo[keep][:n]
        raise ValueError(f"MERL material {self.name!r}: too few valid bins above the horizon to draw {n} samples")


def merl_from_table(table: np.ndarray, path: str | os.PathLike = "<table>", name: str | None = None) -> MERLMaterial:
    metadata = {"source": "merl", "path": str(path), "lookup": "nearest bin",
                "invalid_bins": int((np.asarray(table) < 0).any(axis=0).sum())}
    return MERLMaterial(name or Path(path).stem, table, metadata)


def load_merl(path: str | os.PathLike, name: str | None = None) -> MERLMaterial:
    """Read the MERL ``.binary`` at ``path``; ``name`` defaults to the file's stem."""
    return merl_from_table(read_merl(path), path, name)


# -- writing ---------------------------------------------------------------------------------
def tabulate_merl(evaluate_fn: Evaluate, *, chunk: int = 10 * N_THETA_D * N_PHI_D) -> np.ndarray:
    """``evaluate_fn`` (wi, wo -> (n, 3) f_r) at every bin centre: (3, 90, 90, 180) float64 f_r,
    ``INVALID × scale`` (negative) where a direction of the centre is at or below the horizon.

    Negative values of ``evaluate_fn`` are clipped at 0 (f_r is non-negative); non-finite ones are
    an error.
    """
    out = np.empty((N_BINS, 3), dtype=np.float64)
    for start in range(0, N_BINS, chunk):
        stop = min(start + chunk, N_BINS)
        wi, wo = bin_centre_directions(start, stop)
        above = ((wi[:, 2] > 0) & (wo[:, 2] > 0)).numpy()
        f = evaluate_fn(wi, wo)
        f = f.detach().cpu().numpy() if isinstance(f, torch.Tensor) else np.asarray(f)
        f = np.asarray(f, dtype=np.float64)
        if f.shape != (stop - start, 3):
            raise ValueError(f"evaluate_fn must return shape ({stop - start}, 3), got {f.shape}")
        bad = above[:, None] & ~np.isfinite(f)
        if bad.any():
            row = int(np.nonzero(bad.any(axis=1))[0][0])
            raise ValueError(f"evaluate_fn returned non-finite f_r {f[row].tolist()} at wi={wi[row].tolist()}, "
                             f"wo={wo[row].tolist()}")
        out[start:stop] = np.where(above[:, None], np.clip(np.nan_to_num(f), 0.0, None), INVALID * SCALE)
    return out.T.reshape(3, *DIMS)


def write_merl(path: str | os.PathLike, evaluate_fn: Evaluate | np.ndarray) -> Path:
    """Write a MERL ``.binary`` of ``evaluate_fn`` tabulated at the bin centres (see
    ``tabulate_merl``), or of a ready (3, 90, 90, 180) f_r table; atomically (temp + rename)."""
    path = Path(path)
    table = evaluate_fn if isinstance(evaluate_fn, np.ndarray) else tabulate_merl(evaluate_fn)
    table = np.asarray(table, dtype=np.float64)
    if table.shape != (3, *DIMS):
        raise ValueError(f"a MERL table must have shape {(3, *DIMS)}, got {table.shape}")
    raw = np.where(table < 0, INVALID, table / SCALE.reshape(3, 1, 1, 1))
    return atomic_write(path, HEADER + raw.astype("<f8").tobytes())


def as_directions(wi, wo) -> tuple[torch.Tensor, torch.Tensor]:
    """Direction pairs (n, 3) as float64 CPU tensors, shapes checked."""
    wi = torch.as_tensor(wi).detach().to("cpu", torch.float64)
    wo = torch.as_tensor(wo).detach().to("cpu", torch.float64)
    for label, v in (("wi", wi), ("wo", wo)):
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"{label} must have shape (n, 3), got {tuple(v.shape)}")
    if wi.shape != wo.shape:
        raise ValueError(f"wi and wo must have the same shape, got {tuple(wi.shape)} and {tuple(wo.shape)}")
    return wi, wo
