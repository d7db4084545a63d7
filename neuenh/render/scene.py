"""The scene: an orthographic camera looking at a unit sphere, as per-pixel shading data.

World frame: x to the right of the image, y up, z towards the camera. The camera looks along
-z; pixel (row i, col j) is the ray through ``x = -e + (j + 1/2) 2e / W``,
``y = e - (i + 1/2) 2e / H`` (``e`` = ``extent``, the half-width of the view; rows go down).
The sphere is centred at the origin with radius 1, its poles on the y axis.

Per covered pixel: the hit point, the normal ``n``, the tangent ``t`` along increasing
longitude (the direction of ∂p/∂φ about the y axis, so an anisotropic material's ``alpha_x``
runs around the sphere, like a lathe-brushed ball), the bitangent ``b = n × t`` and the view
direction ``wo`` both in world space and in the local shading frame (x = t, y = b, z = n), the
convention of ``BRDFModel.evaluate``.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

_POLE_EPS = 1e-12  # |∂p/∂φ|² below this: a pole, where longitude has no direction


@dataclass(frozen=True)
class SphereScene:
    """Per-pixel shading data of a unit sphere seen by an orthographic camera.

    ``mask`` (H, W) bool marks the pixels whose ray hits the sphere; the other fields are
    (H, W, 3) float64 and zero outside the mask."""

    mask: torch.Tensor
    position: torch.Tensor
    normal: torch.Tensor
    tangent: torch.Tensor
    bitangent: torch.Tensor
    wo_world: torch.Tensor
    wo_local: torch.Tensor

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.mask.shape)

    def frames(self) -> torch.Tensor:
        """(P, 3, 3) shading frames of the P covered pixels (row-major order): rows t, b, n, so
        ``frames @ d`` takes a world direction ``d`` into the local frame."""
        return torch.stack([self.tangent[self.mask], self.bitangent[self.mask], self.normal[self.mask]], dim=1)


def sphere_scene(width: int, height: int | None = None, *, extent: float = 1.1) -> SphereScene:
    """The unit sphere seen orthographically through a ``width`` × ``height`` (default square)
    image covering [-extent, extent] on the shorter axis (a margin around the silhouette by
    default)."""
    height = width if height is None else height
    if width < 1 or height < 1:
        raise ValueError(f"resolution must be positive, got {width}x{height}")
    if extent <= 0:
        raise ValueError(f"extent must be positive, got {extent}")
    # pixel size: the shorter axis spans 2·extent, pixels are square
    pixel = 2.0 * extent / min(width, height)
    # pixel centres in world units (x right, y up; row 0 at the top)
    x = (torch.arange(width, dtype=torch.float64) + 0.5 - width / 2) * pixel
    y = (height / 2 - torch.arange(height, dtype=torch.float64) - 0.5) * pixel
    yy, xx = torch.meshgrid(y, x, indexing="ij")
    # a ray along -z hits the unit sphere where x² + y² < 1, at z = sqrt(1 - x² - y²) (front side)
    r2 = xx**2 + yy**2
    mask = r2 < 1.0
    zz = torch.sqrt((1.0 - r2).clamp_min(0.0))
    # the hit point of a unit sphere at the origin is its own normal
    position = torch.stack([xx, yy, zz], dim=-1) * mask[..., None]
    normal = position.clone()
    # tangent: ∂p/∂φ for p = (sinθ sinφ, cosθ, sinθ cosφ) is sinθ (cosφ, 0, -sinφ) = (n_z, 0, -n_x)
    tangent = torch.stack([normal[..., 2], torch.zeros_like(xx), -normal[..., 0]], dim=-1)
    length2 = (tangent**2).sum(-1, keepdim=True)
    # at a pole longitude is undefined: fall back on the world x axis (orthogonal to n = ±y)
    pole = length2 < _POLE_EPS
    fallback = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64).expand_as(tangent)
    tangent = torch.where(pole, fallback, tangent / length2.clamp_min(_POLE_EPS).sqrt()) * mask[..., None]
    # bitangent completes the right-handed frame (x = t, y = b, z = n): b = n × t
    bitangent = torch.linalg.cross(normal, tangent, dim=-1)
    # the orthographic camera sees every point from the same direction, +z
    wo_world = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64).expand_as(normal) * mask[..., None]
    # wo in the shading frame: its projections on t, b, n
    wo_local = torch.stack([(wo_world * f).sum(-1) for f in (tangent, bitangent, normal)], dim=-1)
    return SphereScene(mask, position, normal, tangent, bitangent, wo_world.contiguous(), wo_local)
