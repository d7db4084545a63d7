"""The scenes: an orthographic camera looking at a unit sphere, alone (:func:`sphere_scene`) or
resting on a ground plane that shadows it and that it shadows (:func:`ball_scene`), as per-pixel
shading data.

World frame: x to the right of the image, y up, z towards the camera. The camera looks along
-z; pixel (row i, col j) is the ray through ``x = -e + (j + 1/2) 2e / W``,
``y = e - (i + 1/2) 2e / H`` (``e`` = ``extent``, the half-width of the view; rows go down).
The sphere is centred at the origin with radius 1, its poles on the y axis.

Per covered pixel: the hit point, the normal ``n``, the tangent ``t`` along increasing
longitude (the direction of ∂p/∂φ about the y axis, so an anisotropic material's ``alpha_x``
runs around the sphere, like a lathe-brushed ball), the bitangent ``b = n × t`` and the view
direction ``wo`` both in world space and in the local shading frame (x = t, y = b, z = n), the
convention of ``BRDFModel.evaluate``.

**The ball scene** (a material-ball-like stage, with visibility): the same sphere resting on the
plane ``y = -1`` (a disc of radius ``ground_radius``), seen from ``elevation`` degrees above the
horizon. The plane is Lambertian with albedo ``ground_albedo`` in every render (``ground`` marks its
pixels, shaded with the frame t = x, b = -z, n = y); only the sphere carries the BRDF under test.
Light is direct only: a direction towards the light is blocked by the plane for the sphere
(``d_y < 0``) and by the sphere for the plane (the ray meets it); :meth:`SphereScene.visible`
answers it, for every BRDF alike, so renders still share their noise.
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
    ground: torch.Tensor | None = None  # (H, W) bool: ground-plane pixels (ball scene), or None
    ground_albedo: float = 0.18

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.mask.shape)

    @property
    def shadowed(self) -> bool:
        """Whether anything can block the light (the ball scene): the renderer then asks
        :meth:`visible`."""
        return self.ground is not None

    def visible(self, points: torch.Tensor, directions: torch.Tensor, on_ground: torch.Tensor) -> torch.Tensor:
        """(P, K) bool: whether the ray from ``points`` (P, 3) along world ``directions`` (P, K, 3)
        escapes the scene. ``on_ground`` (P,) marks points on the plane: only the sphere can block
        them; for points on the sphere, only the plane can (a sphere never shadows itself)."""
        if not self.shadowed:
            return torch.ones(directions.shape[:2], dtype=torch.bool)
        below = directions[..., 1] < 0  # towards the plane y = -1, which lies below every point
        # |p + t d|² = 1: t² + 2 (p·d) t + |p|² - 1 = 0 has a root t > 0 when p·d < 0 and the
        # discriminant is positive (|p| > 1 for a point on the plane off the contact point)
        pd = torch.einsum("pj,pkj->pk", points, directions)
        hits_sphere = (pd < 0) & (pd**2 - ((points**2).sum(-1, keepdim=True) - 1.0) > 0)
        return torch.where(on_ground[:, None], ~hits_sphere, ~below)

    def frames(self, pixels: torch.Tensor | None = None) -> torch.Tensor:
        """(P, 3, 3) shading frames of the P pixels of ``pixels`` (default: the sphere's ``mask``),
        in row-major order: rows t, b, n, so ``frames @ d`` takes a world direction into the local frame."""
        pixels = self.mask if pixels is None else pixels
        return torch.stack([self.tangent[pixels], self.bitangent[pixels], self.normal[pixels]], dim=1)


def _pixel_grid(width: int, height: int | None, extent: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(yy, xx) (H, W): pixel centres in image-plane units, square pixels, the shorter axis spanning
    [-extent, extent] (x right, y up; row 0 at the top)."""
    height = width if height is None else height
    if width < 1 or height < 1:
        raise ValueError(f"resolution must be positive, got {width}x{height}")
    if extent <= 0:
        raise ValueError(f"extent must be positive, got {extent}")
    pixel = 2.0 * extent / min(width, height)
    x = (torch.arange(width, dtype=torch.float64) + 0.5 - width / 2) * pixel
    y = (height / 2 - torch.arange(height, dtype=torch.float64) - 0.5) * pixel
    return torch.meshgrid(y, x, indexing="ij")


def _longitude_tangent(normal: torch.Tensor) -> torch.Tensor:
    """Unit tangents along increasing longitude about y at unit-sphere normals (..., 3)."""
    # ∂p/∂φ for p = (sinθ sinφ, cosθ, sinθ cosφ) is sinθ (cosφ, 0, -sinφ) = (n_z, 0, -n_x)
    tangent = torch.stack([normal[..., 2], torch.zeros_like(normal[..., 0]), -normal[..., 0]], dim=-1)
    length2 = (tangent**2).sum(-1, keepdim=True)
    # at a pole longitude is undefined: fall back on the world x axis (orthogonal to n = ±y)
    fallback = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64).expand_as(tangent)
    return torch.where(length2 < _POLE_EPS, fallback, tangent / length2.clamp_min(_POLE_EPS).sqrt())


def _shading(mask, covered, position, normal, tangent, view, **extra) -> SphereScene:
    """The scene from per-pixel ``normal`` and ``tangent``: the bitangent completes the
    right-handed frame, ``wo`` is ``-view`` everywhere (orthographic), and every field is zero
    outside ``covered`` (H, W)."""
    keep = covered[..., None]
    normal, tangent = normal * keep, tangent * keep
    bitangent = torch.linalg.cross(normal, tangent, dim=-1)  # b = n × t: x = t, y = b, z = n
    wo_world = (-view).expand_as(normal) * keep
    # wo in the shading frame: its projections on t, b, n
    wo_local = torch.stack([(wo_world * f).sum(-1) for f in (tangent, bitangent, normal)], dim=-1)
    return SphereScene(mask, position * keep, normal, tangent, bitangent, wo_world.contiguous(), wo_local, **extra)


def sphere_scene(width: int, height: int | None = None, *, extent: float = 1.1) -> SphereScene:
    """The unit sphere seen orthographically through a ``width`` × ``height`` (default square)
    image covering [-extent, extent] on the shorter axis (a margin around the silhouette by
    default)."""
    yy, xx = _pixel_grid(width, height, extent)
    # a ray along -z hits the unit sphere where x² + y² < 1, at z = sqrt(1 - x² - y²) (front side)
    r2 = xx**2 + yy**2
    mask = r2 < 1.0
    zz = torch.sqrt((1.0 - r2).clamp_min(0.0))
    # the hit point of a unit sphere at the origin is its own normal
    position = torch.stack([xx, yy, zz], dim=-1) * mask[..., None]
    view = torch.tensor([0.0, 0.0, -1.0], dtype=torch.float64)  # the camera looks along -z
    return _shading(mask, mask, position, position, _longitude_tangent(position), view)


def ball_scene(width: int, height: int | None = None, *, elevation: float = 20.0, extent: float = 1.6,
               ground_radius: float = 4.0, ground_albedo: float = 0.18) -> SphereScene:
    """The unit sphere on the plane y = -1 (module doc), seen orthographically from ``elevation``
    degrees above the horizon through a ``width`` × ``height`` image covering ±``extent`` on the
    shorter axis, centred on the sphere. ``mask`` marks the sphere's pixels, ``ground`` the plane's."""
    if not 0 < elevation < 90:
        raise ValueError(f"elevation must be between 0 and 90 degrees, got {elevation}")
    yy, xx = _pixel_grid(width, height, extent)
    e = torch.deg2rad(torch.tensor(elevation, dtype=torch.float64))
    view = torch.stack([torch.zeros(()), -torch.sin(e), -torch.cos(e)]).double()  # where the camera looks
    right = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    up = torch.linalg.cross(right, view)  # completes the camera frame: up = right × view
    # ray origins on the image plane, far enough back that everything lies ahead (t > 0)
    origin = xx[..., None] * right + yy[..., None] * up - 10.0 * view
    # the sphere: |o + t v|² = 1, nearer root; the plane: o_y + t v_y = -1
    ov = (origin * view).sum(-1)
    disc = ov**2 - ((origin**2).sum(-1) - 1.0)
    t_sphere = torch.where(disc > 0, -ov - disc.clamp_min(0).sqrt(), torch.full_like(ov, float("inf")))
    t_plane = (-1.0 - origin[..., 1]) / view[1]
    on_plane = origin + t_plane[..., None] * view
    plane_hit = (on_plane[..., 0] ** 2 + on_plane[..., 2] ** 2) < ground_radius**2
    t_plane = torch.where(plane_hit, t_plane, torch.full_like(t_plane, float("inf")))
    mask = torch.isfinite(t_sphere) & (t_sphere <= t_plane)
    ground = torch.isfinite(t_plane) & ~mask
    t = torch.where(mask, t_sphere, torch.where(ground, t_plane, torch.zeros_like(t_plane)))
    position = origin + t[..., None] * view
    # sphere pixels: longitude tangents as in sphere_scene; ground pixels: t = x, b = -z, n = y
    plane_normal, plane_tangent = (torch.tensor(v, dtype=torch.float64).expand_as(position)
                                   for v in ((0.0, 1.0, 0.0), (1.0, 0.0, 0.0)))
    sphere = mask[..., None]
    normal = torch.where(sphere, position, plane_normal)
    tangent = torch.where(sphere, _longitude_tangent(position), plane_tangent)
    return _shading(mask, mask | ground, position, normal, tangent, view, ground=ground, ground_albedo=ground_albedo)
