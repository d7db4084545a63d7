"""Shading geometry: from local-frame directions and per-sample parameters to the quantities
every BRDF term reads.

Conventions (DESIGN §4): ``wi`` and ``wo`` are ``(n, 3)`` unit vectors in the local frame whose
z axis is the geometric normal and whose x axis is the tangent *before* rotation by ``t_theta``.
The shading normal is tilted by the two ``normal`` angles (slopes along x and y:
``n ∝ (tan a, tan b, 1)``, so ``(0, 0)`` is the geometric normal, which is the mean of the range).
The tangent is the geometric x axis carried along by the smallest rotation taking z to n, then
rotated about n by ``t_theta``.

Directions below either horizon (geometric or shading) give a BRDF of exactly zero; on those rows
the terms see normal incidence and exitance. All cosines read by the terms are clamped to
``COS_EPS`` first, so formulas are evaluated only on safe values and both values and gradients
stay finite; the mask is applied afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import torch

# Smallest cosine a term ever sees. 1/(4 cos_i cos_o) stays below 1e12 (finite in float32); grazing
# directions up to 89.9 degrees (cos = 1.7e-3) are far above it and evaluated exactly.
COS_EPS = 1e-6


@dataclass
class Shading:
    """Everything a term may read, for n samples. Directions are in the shading frame."""

    wi: torch.Tensor  # (n, 3) incident direction, shading frame
    wo: torch.Tensor  # (n, 3) outgoing direction, shading frame
    h: torch.Tensor  # (n, 3) half vector normalize(wi + wo), shading frame
    cos_i: torch.Tensor  # (n, 1) wi.z clamped to COS_EPS
    cos_o: torch.Tensor  # (n, 1) wo.z clamped to COS_EPS
    cos_h: torch.Tensor  # (n, 1) h.z clamped to COS_EPS
    cos_d: torch.Tensor  # (n, 1) wi.h (= wo.h) clamped to [COS_EPS, 1]
    params: Mapping[str, torch.Tensor]  # physical parameter values, each (n, width)
    above: torch.Tensor  # (n, 1) bool: both directions above both horizons

    @property
    def n(self) -> int:
        return self.wi.shape[0]


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a * b).sum(dim=-1, keepdim=True)


def shading_normal(slopes: torch.Tensor) -> torch.Tensor:
    """``normal`` angles (n, 2) -> unit shading normal (n, 3), ``n ∝ (tan a, tan b, 1)``."""
    n = torch.cat([torch.tan(slopes), torch.ones_like(slopes[:, :1])], dim=-1)
    return n / torch.linalg.vector_norm(n, dim=-1, keepdim=True)


def shading_frame(
    normal_angles: torch.Tensor | None, t_theta: torch.Tensor | None, like: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Orthonormal (tangent, bitangent, normal), each (n, 3), in the local frame."""
    n_samples = like.shape[0]
    if normal_angles is None:
        normal = like.new_tensor([0.0, 0.0, 1.0]).expand(n_samples, 3)
    else:
        normal = shading_normal(normal_angles)
    nx, ny, nz = normal[:, 0:1], normal[:, 1:2], normal[:, 2:3]
    # The smallest rotation taking z to n maps x and y to these (nz > 0 for every allowed tilt).
    k = 1.0 / (1.0 + nz)
    t0 = torch.cat([1.0 - nx * nx * k, -nx * ny * k, -nx], dim=-1)
    b0 = torch.cat([-nx * ny * k, 1.0 - ny * ny * k, -ny], dim=-1)
    if t_theta is None:
        return t0, b0, normal
    c, s = torch.cos(t_theta), torch.sin(t_theta)
    return c * t0 + s * b0, c * b0 - s * t0, normal


def to_frame(
    w: torch.Tensor, frame: tuple[torch.Tensor, torch.Tensor, torch.Tensor]
) -> torch.Tensor:
    t, b, n = frame
    return torch.cat([_dot(w, t), _dot(w, b), _dot(w, n)], dim=-1)


def make_shading(
    wi: torch.Tensor, wo: torch.Tensor, params: Mapping[str, torch.Tensor]
) -> Shading:
    """Build the shading context. ``params`` are physical values already broadcast to (n, w)."""
    frame = shading_frame(params.get("normal"), params.get("t_theta"), wi)
    wi_s, wo_s = to_frame(wi, frame), to_frame(wo, frame)
    above = (wi[:, 2:3] > 0) & (wo[:, 2:3] > 0) & (wi_s[:, 2:3] > 0) & (wo_s[:, 2:3] > 0)
    # Rows below a horizon are masked to zero, but their terms are still evaluated (and
    # differentiated): give them normal incidence and exitance. Otherwise a half vector pointing
    # into the surface (e.g. wi = wo = -n) leaves h_z clamped to COS_EPS with h_x = h_y = 0, GGX's
    # D = 1/(pi a_x a_y COS_EPS^4) and its derivative overflow in float32, and the mask's zero
    # gradient times that inf poisons every parameter with NaN.
    up = torch.zeros_like(wi_s)
    up[:, 2] = 1.0
    wi_s, wo_s = torch.where(above, wi_s, up), torch.where(above, wo_s, up)
    # Both directions are now above the shading horizon, so wi + wo never vanishes.
    half = wi_s + wo_s
    h = half / torch.linalg.vector_norm(half, dim=-1, keepdim=True)
    return Shading(
        wi=wi_s,
        wo=wo_s,
        h=h,
        cos_i=wi_s[:, 2:3].clamp_min(COS_EPS),
        cos_o=wo_s[:, 2:3].clamp_min(COS_EPS),
        cos_h=h[:, 2:3].clamp_min(COS_EPS),
        cos_d=_dot(wi_s, h).clamp(COS_EPS, 1.0),
        params=params,
        above=above,
    )
