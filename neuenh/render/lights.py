"""Lights: directional lights and a lat-long environment map, as fixed sets of light samples.

Every light turns into ``LightSamples``: world directions (towards the light), their radiance
and their pdf, and the weight each sample carries in the renderer's estimator

    L_o(wo) = Σ_k f_r(wi_k, wo) · max(cos θ_k, 0) · weight_k.

**Directional light** (a delta light): one sample, its direction, radiance = its irradiance E at
normal incidence (RGB), pdf 1 by convention, weight = E. No noise.

**Environment map**: an (H, W, 3) linear RGB lat-long image (e.g. ``EnvironmentMap.from_exr``).
Row i covers the polar angle θ ∈ [iπ/H, (i+1)π/H] measured from +y (row 0 is the sky's
zenith), column j the azimuth φ ∈ [2πj/W, 2π(j+1)/W); the direction of (θ, φ) is
``(sinθ sinφ, cosθ, sinθ cosφ)`` (φ = 0 is +z, towards the camera of ``scene.py``; φ = π/2 is
+x). Radiance is constant over a texel (nearest lookup).

Importance sampling (Pharr, Jakob, Humphreys, *PBRT* 3rd ed., Sec. 14.2.4, with the texel's
exact solid angle in place of sin θ): texel (i, j) is chosen with probability
``P_ij ∝ lum_ij · ΔΩ_i`` (lum: Rec. 709 luminance; ``ΔΩ_i = Δφ (cos θ_i - cos θ_{i+1})``, i.e.
sin θ times the texel's angular area) by inverting the row marginal CDF, then the column CDF
of that row; inside the texel the direction is uniform in solid angle (uniform in cos θ and φ),
so ``pdf(ω) = P_ij / ΔΩ_i = lum_ij / Σ lum·ΔΩ`` is constant over a texel and ``L / pdf`` is
constant over it too. The unit-square samples are a jittered n × n stratified grid from a
seeded generator, drawn once and kept: every BRDF rendered with this map sees the very same
directions, so a ground truth and a model share their noise. A constant map turns into exactly
stratified uniform sphere sampling (cos θ = 1 - 2u₁, φ = 2πu₂).

These samples are the renderer's ``sampling="light"`` estimator. The default, ``"mis"``
(``sampling.py``), uses the same inversion (``EnvironmentMap.sample_directions``) as one strategy
of a BRDF-independent mixture, and ``EnvironmentMap.lookup`` for the radiance and density at the
other strategies' directions.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from functools import cached_property
from typing import Sequence

import numpy as np
import torch

LUMINANCE = (0.2126, 0.7152, 0.0722)  # Rec. 709 / sRGB primaries, linear RGB -> Y


@dataclass(frozen=True)
class LightSamples:
    """k light samples: world ``direction`` (k, 3) towards the light, ``radiance`` (k, 3),
    ``pdf`` (k,) in solid angle (1 for delta lights) and the estimator ``weight`` (k, 3)."""

    direction: torch.Tensor
    radiance: torch.Tensor
    pdf: torch.Tensor
    weight: torch.Tensor

    def __len__(self) -> int:
        return self.direction.shape[0]

    @staticmethod
    def concat(parts: Sequence["LightSamples"]) -> "LightSamples":
        if not parts:
            raise ValueError("no lights")
        fields = ("direction", "radiance", "pdf", "weight")
        return LightSamples(*(torch.cat([getattr(p, f) for p in parts]) for f in fields))


@dataclass(frozen=True)
class DirectionalLight:
    """A distant light from ``direction`` (world, towards the light; normalised here) giving
    irradiance ``radiance`` (RGB, or one value for white) on a surface facing it."""

    direction: tuple[float, float, float]
    radiance: tuple[float, float, float] | float = 1.0

    def samples(self) -> LightSamples:
        d = torch.as_tensor(self.direction, dtype=torch.float64).reshape(1, 3)
        norm = torch.linalg.vector_norm(d)
        if not torch.isfinite(norm) or norm == 0:
            raise ValueError(f"a directional light needs a non-zero direction, got {self.direction}")
        e = torch.as_tensor(self.radiance, dtype=torch.float64).expand(3).reshape(1, 3).clone()
        # a delta light: one exact sample, pdf 1 by convention, weight = E
        return LightSamples(d / norm, e, torch.ones(1, dtype=torch.float64), e)


@dataclass(eq=False)
class EnvironmentMap:
    """A lat-long environment map (see the module docstring) sampled with ``samples_per_axis``²
    fixed stratified samples drawn from ``seed``."""

    image: torch.Tensor  # (H, W, 3) float64 linear RGB radiance
    samples_per_axis: int = 32
    seed: int = 0
    _cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        image = self.image
        if isinstance(image, np.ndarray):
            image = torch.from_numpy(np.ascontiguousarray(image))
        image = torch.as_tensor(image, dtype=torch.float64)
        if image.ndim != 3 or image.shape[2] != 3 or image.shape[0] < 1 or image.shape[1] < 1:
            raise ValueError(f"an environment map must be an (H, W, 3) image, got shape {tuple(image.shape)}")
        if not torch.isfinite(image).all() or (image < 0).any():
            raise ValueError("an environment map must hold finite, non-negative radiance")
        if self.samples_per_axis < 1:
            raise ValueError(f"samples_per_axis must be >= 1, got {self.samples_per_axis}")
        self.image = image
        if float((self._luminance * self._solid_angle[:, None]).sum()) <= 0:
            raise ValueError("an environment map must emit some light (it is black)")

    @classmethod
    def from_exr(cls, path: str | os.PathLike, **kwargs) -> "EnvironmentMap":
        """The R, G, B channels of a lat-long EXR image (``neuenh.data.exr.read_rgb_exr``)."""
        from ..data.exr import read_rgb_exr

        return cls(torch.from_numpy(read_rgb_exr(path).astype(np.float64)), **kwargs)

    @classmethod
    def constant(cls, radiance=1.0, height: int = 8, width: int = 16, **kwargs) -> "EnvironmentMap":
        """A uniform environment (the white furnace for radiance 1)."""
        rgb = torch.as_tensor(radiance, dtype=torch.float64).expand(3)
        return cls(rgb.expand(height, width, 3).clone(), **kwargs)

    # -- geometry of the texels -------------------------------------------------------------
    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.image.shape[:2])

    @cached_property
    def _cos_edges(self) -> torch.Tensor:
        """cos θ at the H + 1 row edges, from +1 (zenith) down to -1."""
        h = self.shape[0]
        return torch.cos(torch.arange(h + 1, dtype=torch.float64) * math.pi / h)

    @cached_property
    def _solid_angle(self) -> torch.Tensor:
        """(H,) solid angle of one texel of each row: Δφ (cos θ_i - cos θ_{i+1})."""
        return (2 * math.pi / self.shape[1]) * (self._cos_edges[:-1] - self._cos_edges[1:])

    @cached_property
    def _luminance(self) -> torch.Tensor:
        return self.image @ torch.tensor(LUMINANCE, dtype=torch.float64)

    @cached_property
    def _distribution(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, float]:
        """Row CDF (H + 1,), per-row column CDFs (H, W + 1), texel weights and their total."""
        # texel weight: luminance × solid angle (∝ luminance × sin θ)
        weight = self._luminance * self._solid_angle[:, None]
        total = float(weight.sum())
        # row marginal CDF, exactly 1 at the end so every u < 1 lands in a row of non-zero mass
        row_cdf = torch.cat([torch.zeros(1, dtype=torch.float64), weight.sum(1).cumsum(0) / total])
        row_cdf[-1] = 1.0
        # conditional column CDF of every row (rows without light keep a flat CDF, never chosen)
        row_sum = weight.sum(1, keepdim=True)
        col_cdf = torch.cat([torch.zeros_like(row_sum), weight.cumsum(1) / row_sum.clamp_min(1e-300)], dim=1)
        col_cdf[:, -1] = 1.0
        return row_cdf, col_cdf, weight, total

    def texel(self, direction: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Row and column indices of world directions (n, 3)."""
        d = torch.as_tensor(direction, dtype=torch.float64)
        d = d / torch.linalg.vector_norm(d, dim=-1, keepdim=True)
        h, w = self.shape
        # θ from +y, φ from +z towards +x, wrapped to [0, 2π)
        theta = torch.arccos(d[:, 1].clamp(-1.0, 1.0))
        phi = torch.atan2(d[:, 0], d[:, 2]) % (2 * math.pi)
        row = (theta / math.pi * h).long().clamp(0, h - 1)
        col = (phi / (2 * math.pi) * w).long().clamp(0, w - 1)
        return row, col

    def radiance(self, direction: torch.Tensor) -> torch.Tensor:
        """(n, 3) radiance arriving from world directions (nearest texel)."""
        row, col = self.texel(direction)
        return self.image[row, col]

    def pdf(self, direction: torch.Tensor) -> torch.Tensor:
        """(n,) solid-angle density of the sampler at world directions."""
        row, col = self.texel(direction)
        return self._luminance[row, col] / self._distribution[3]

    def lookup(self, direction: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``radiance`` (n, 3) and ``pdf`` (n,) at world directions, with one texel lookup."""
        row, col = self.texel(direction)
        return self.image[row, col], self._luminance[row, col] / self._distribution[3]

    # -- the fixed samples ------------------------------------------------------------------
    def samples(self) -> LightSamples:
        """The map's fixed stratified samples (computed once, then the same object)."""
        if "samples" not in self._cache:
            self._cache["samples"] = self._draw()
        return self._cache["samples"]

    def _draw(self) -> LightSamples:
        n = self.samples_per_axis
        # jittered n × n grid in the unit square, from a seeded generator
        generator = torch.Generator().manual_seed(self.seed)
        cell = torch.arange(n, dtype=torch.float64)
        g1, g2 = torch.meshgrid(cell, cell, indexing="ij")
        jitter = torch.rand(n * n, 2, generator=generator, dtype=torch.float64)
        u1 = ((g1.reshape(-1) + jitter[:, 0]) / n).clamp(0.0, 1.0 - 1e-12)
        u2 = ((g2.reshape(-1) + jitter[:, 1]) / n).clamp(0.0, 1.0 - 1e-12)
        direction, pdf, radiance = self.sample_directions(torch.stack([u1, u2], dim=-1))
        # Monte Carlo weight: L / (pdf · N)
        return LightSamples(direction, radiance, pdf, radiance / (pdf[:, None] * (n * n)))

    def sample_directions(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """World directions (m, 3), their pdf (m,) and radiance (m, 3) of unit-square points
        ``u`` (m, 2) in [0, 1): the inversion of the texel distribution (module docstring)."""
        h, w = self.shape
        row_cdf, col_cdf, weight, total = self._distribution
        u1, u2 = u[:, 0].contiguous(), u[:, 1].contiguous()
        # row: the first row whose CDF exceeds u1; the remainder, rescaled, places cos θ in it
        row = (torch.searchsorted(row_cdf, u1, right=True) - 1).clamp(0, h - 1)
        r1 = (u1 - row_cdf[row]) / (row_cdf[row + 1] - row_cdf[row])
        # column: the same inversion within the chosen row's conditional CDF
        cdf = col_cdf[row]
        col = (torch.searchsorted(cdf, u2[:, None], right=True).squeeze(1) - 1).clamp(0, w - 1)
        c_lo, c_hi = cdf.gather(1, col[:, None]).squeeze(1), cdf.gather(1, (col + 1)[:, None]).squeeze(1)
        r2 = (u2 - c_lo) / (c_hi - c_lo)
        # uniform in solid angle inside the texel: linear in cos θ, linear in φ
        cos_t = self._cos_edges[row] + r1.clamp(0, 1) * (self._cos_edges[row + 1] - self._cos_edges[row])
        sin_t = torch.sqrt((1.0 - cos_t**2).clamp_min(0.0))
        phi = (col + r2.clamp(0, 1)) * (2 * math.pi / w)
        direction = torch.stack([sin_t * torch.sin(phi), cos_t, sin_t * torch.cos(phi)], dim=-1)
        # pdf in solid angle: P_ij / ΔΩ_i
        pdf = weight[row, col] / total / self._solid_angle[row]
        return direction, pdf, self.image[row, col]


Light = DirectionalLight | EnvironmentMap


def gather(lights: Light | Sequence[Light]) -> LightSamples:
    """Every light's samples in one set."""
    if isinstance(lights, (DirectionalLight, EnvironmentMap)):
        lights = [lights]
    return LightSamples.concat([light.samples() for light in lights])
