"""Direction pairs drawn uniformly in Rusinkiewicz coordinates (paper Sec. 6).

Rusinkiewicz, "A New Change of Variables for Efficient BRDF Representation", EGWR 1998: a pair is
(theta_h, phi_h) of the half vector and (theta_d, phi_d) of the "difference" vector, i.e. wi
expressed in a frame whose z axis is h. Uniform sampling of these angles concentrates samples near
the specular peak, which is where reflectance varies fastest. Isotropic materials use phi_h = 0
(three angles); anisotropic ones draw phi_h too.

``Sampling`` says how a training set or a fit set draws its pairs (issue 14): a share of them *near
the mirror direction* (the half vector within ``MIRROR_DEG`` of the normal, the way
``../shared/data/rgl/reference_values.npz`` draws half its pairs, since highlights are what users
see and where models differ), and isotropic materials over every azimuth phi_h instead of phi_h = 0
only (a shared model's modules read raw directions, so they learn azimuthal invariance only from
data that varies in azimuth).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

MIRROR_DEG = 10.0  # "near the mirror direction": theta_h at most this many degrees


def from_rusinkiewicz(
    theta_h: torch.Tensor, phi_h: torch.Tensor, theta_d: torch.Tensor, phi_d: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Angles (n,) -> unit ``wi, wo`` (n, 3) in the local frame."""
    h = torch.stack(
        [torch.sin(theta_h) * torch.cos(phi_h), torch.sin(theta_h) * torch.sin(phi_h), torch.cos(theta_h)],
        dim=-1,
    )
    d = torch.stack(
        [torch.sin(theta_d) * torch.cos(phi_d), torch.sin(theta_d) * torch.sin(phi_d), torch.cos(theta_d)],
        dim=-1,
    )
    # wi = Rz(phi_h) Ry(theta_h) d: the frame that carries z onto h.
    ct, st = torch.cos(theta_h), torch.sin(theta_h)
    x = ct * d[:, 0] + st * d[:, 2]
    z = -st * d[:, 0] + ct * d[:, 2]
    y = d[:, 1]
    cp, sp = torch.cos(phi_h), torch.sin(phi_h)
    wi = torch.stack([cp * x - sp * y, sp * x + cp * y, z], dim=-1)
    wo = 2.0 * (wi * h).sum(-1, keepdim=True) * h - wi
    return wi, wo


def to_rusinkiewicz(wi: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """Unit ``wi, wo`` (n, 3) -> (theta_h, phi_h, theta_d, phi_d), the inverse of the above."""
    h = wi + wo
    h = h / torch.linalg.vector_norm(h, dim=-1, keepdim=True)
    theta_h = torch.acos(h[:, 2].clamp(-1, 1))
    phi_h = torch.atan2(h[:, 1], h[:, 0])
    cp, sp = torch.cos(phi_h), torch.sin(phi_h)
    x = cp * wi[:, 0] + sp * wi[:, 1]
    y = -sp * wi[:, 0] + cp * wi[:, 1]
    ct, st = torch.cos(theta_h), torch.sin(theta_h)
    dx = ct * x - st * wi[:, 2]
    dz = st * x + ct * wi[:, 2]
    theta_d = torch.acos(dz.clamp(-1, 1))
    phi_d = torch.atan2(y, dx)
    return theta_h, phi_h, theta_d, phi_d


def sample_directions(
    n: int, *, seed: int, anisotropic: bool = True, near_mirror: float = 0.0,
    dtype: torch.dtype = torch.float64,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` direction pairs uniform in Rusinkiewicz angles, both above the horizon.

    Pairs with either direction at or below the horizon (where every BRDF is zero and so carries
    no information) are rejected and redrawn; the result depends only on the arguments.
    ``near_mirror``: the share of the pairs drawn with theta_h uniform in [0, MIRROR_DEG] instead of
    [0, 90] degrees, from a random stream of their own; they follow the others.
    """
    if n < 0:
        raise ValueError(f"number of samples must be >= 0, got {n}")
    if not 0.0 <= near_mirror <= 1.0:
        raise ValueError(f"near_mirror is a share of the pairs, in [0, 1]; got {near_mirror}")
    near = int(round(n * near_mirror))
    wi, wo = _draw(n - near, seed, anisotropic, math.pi / 2)
    if near:
        mirror = _draw(near, seed ^ 0x4D4952, anisotropic, math.radians(MIRROR_DEG))
        wi, wo = torch.cat([wi, mirror[0]]), torch.cat([wo, mirror[1]])
    return wi.to(dtype), wo.to(dtype)


def _draw(n: int, seed: int, anisotropic: bool, theta_h_max: float) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    wis, wos, have = [torch.empty(0, 3, dtype=torch.float64)], [torch.empty(0, 3, dtype=torch.float64)], 0
    while have < n:
        m = max(2 * (n - have), 1024)
        u = torch.rand(m, 4, generator=generator, dtype=torch.float64)
        theta_h = u[:, 0] * theta_h_max
        phi_h = u[:, 1] * (2 * math.pi) if anisotropic else torch.zeros(m, dtype=torch.float64)
        theta_d = u[:, 2] * (math.pi / 2)
        phi_d = u[:, 3] * (2 * math.pi)
        wi, wo = from_rusinkiewicz(theta_h, phi_h, theta_d, phi_d)
        keep = (wi[:, 2] > 1e-4) & (wo[:, 2] > 1e-4)
        wis.append(wi[keep])
        wos.append(wo[keep])
        have += int(keep.sum())
    return torch.cat(wis)[:n], torch.cat(wos)[:n]


@dataclass(frozen=True)
class Sampling:
    """How a material's measurements are drawn (see the module doc)."""

    near_mirror: float = 0.0  # share of pairs with the half vector within MIRROR_DEG of the normal
    every_azimuth: bool = False  # isotropic materials over every phi_h too (anisotropic ones always)

    def __post_init__(self) -> None:
        if not 0.0 <= self.near_mirror <= 1.0:
            raise ValueError(f"near_mirror is a share of the pairs, in [0, 1]; got {self.near_mirror}")

    def directions(self, n: int, seed: int, isotropic: bool) -> tuple[torch.Tensor, torch.Tensor]:
        """``n`` pairs (float64) for a material, isotropic or not."""
        return sample_directions(n, seed=seed, anisotropic=self.every_azimuth or not isotropic,
                                 near_mirror=self.near_mirror)


def near_mirror_mask(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """(n,) whether each pair's half vector lies within MIRROR_DEG of the normal."""
    h = wi + wo
    cos_h = h[:, 2] / torch.linalg.vector_norm(h, dim=-1).clamp_min(1e-30)
    return cos_h >= math.cos(math.radians(MIRROR_DEG))
