"""Synthetic materials to learn from, seeded and reproducible.

* ``synthetic_ggx``: the paper's anisotropic GGX materials (Sec. 6) with random parameters, whose
  measurements carry multiplicative Gaussian noise N(1, 0.1) to mimic acquisition noise.
* ``synthetic_zoo``: materials plain GGX cannot represent, so enhancement has something real to
  find: conductors with a complex index of refraction, two specular lobes, clear coat, sheen,
  retro-reflection and Oren-Nayar rough diffuse. Each family is a closed form with its citation.

All evaluation is float64; ``f_r`` excludes the cosine factor (the project's convention).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import torch

from ..models.alternatives import conductor_fresnel
from ..models.microfacet import ggx_distribution, smith_shadowing
from ..ops import TORCH
from ..shading import COS_EPS, Shading, make_shading
from .directions import Sampling

Evaluate = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass
class AnalyticMaterial:
    """A material given by a closed form; measurements may carry multiplicative noise."""

    name: str
    evaluate_fn: Evaluate
    isotropic: bool
    noise_sigma: float = 0.0
    metadata: dict = field(default_factory=dict)

    def evaluate(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        """Noise-free f_r (n, 3) at local-frame directions, 0 below the horizon."""
        wi, wo = wi.double(), wo.double()
        above = (wi[:, 2:3] > 0) & (wo[:, 2:3] > 0)
        f = self.evaluate_fn(wi, wo)
        return torch.where(above, f, torch.zeros_like(f))

    def samples(self, n: int, seed: int, sampling: Sampling = Sampling()
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``n`` measurements (wi, wo, f_r) drawn as ``sampling`` says, noisy if ``noise_sigma``."""
        wi, wo = sampling.directions(n, seed, self.isotropic)
        f = self.evaluate(wi, wo)
        if self.noise_sigma:
            generator = torch.Generator().manual_seed(seed ^ 0x5EED)
            noise = 1.0 + self.noise_sigma * torch.randn(f.shape, generator=generator, dtype=f.dtype)
            f = (f * noise).clamp_min(0.0)
        return wi, wo, f


# -- building blocks -------------------------------------------------------------------------
def _shading(wi, wo, **params) -> Shading:
    n = wi.shape[0]
    values = {k: torch.as_tensor(v, dtype=wi.dtype).reshape(1, -1).expand(n, -1) for k, v in params.items()}
    return make_shading(wi, wo, values, TORCH)


def _ggx_lobe(wi, wo, alpha_x, alpha_y, t_theta=0.0):
    """D G / (4 cos_i cos_o) of anisotropic GGX (Walter et al. 2007), without Fresnel."""
    s = _shading(wi, wo, alpha_x=[alpha_x], alpha_y=[alpha_y], t_theta=[t_theta])
    return ggx_distribution(s) * smith_shadowing(s) / (4 * s.cos_i * s.cos_o), s


def dielectric_fresnel(cos: torch.Tensor, eta: float) -> torch.Tensor:
    """Unpolarised Fresnel reflectance from air into a dielectric of IOR eta (Born & Wolf)."""
    cos = cos.clamp(COS_EPS, 1.0)
    sin_t2 = (1.0 - cos * cos) / (eta * eta)
    cos_t = torch.sqrt((1.0 - sin_t2).clamp_min(0.0))
    r_s = (cos - eta * cos_t) / (cos + eta * cos_t)
    r_p = (eta * cos - cos_t) / (eta * cos + cos_t)
    return 0.5 * (r_s * r_s + r_p * r_p)


# Complex IORs at (650, 550, 450) nm, from refractiveindex.info (Rakic 1998; Johnson & Christy 1972).
CONDUCTORS = {
    "gold": ((0.166, 0.425, 1.38), (3.15, 2.35, 1.79)),
    "copper": ((0.214, 1.04, 1.19), (3.67, 2.58, 2.40)),
    "aluminium": ((1.47, 0.96, 0.62), (7.79, 6.69, 5.45)),
    "silver": ((0.15, 0.12, 0.14), (4.14, 3.35, 2.47)),
    "chromium": ((3.18, 3.18, 2.30), (3.33, 3.33, 3.13)),
    "iron": ((2.87, 2.92, 2.53), (3.08, 2.93, 2.79)),
}


# -- the zoo ---------------------------------------------------------------------------------
def _conductor(g: torch.Generator, i: int) -> AnalyticMaterial:
    metal = list(CONDUCTORS)[int(torch.randint(len(CONDUCTORS), (1,), generator=g))]
    eta, k = (torch.tensor(v, dtype=torch.float64) for v in CONDUCTORS[metal])
    ax, ay = _log_uniform(g, 0.03, 0.4, 2)
    t_theta = _uniform(g, -math.pi / 2, math.pi / 2)

    def f(wi, wo):
        lobe, s = _ggx_lobe(wi, wo, ax, ay, t_theta)
        return lobe * conductor_fresnel(TORCH, s.cos_d, eta, k)  # the model's exact formula; cos_d in [COS_EPS, 1]

    return AnalyticMaterial(f"conductor-{metal}-{i:03d}", f, isotropic=False,
                            metadata={"family": "conductor", "metal": metal, "alpha": (ax, ay)})


def _two_lobes(g: torch.Generator, i: int) -> AnalyticMaterial:
    """A sharp lobe over a wide haze (cf. Barla et al. 2018 "hazy gloss"): no single GGX fits it."""
    sharp = _log_uniform(g, 0.02, 0.08, 1)[0]
    haze = _log_uniform(g, 0.25, 0.6, 1)[0]
    weight = _uniform(g, 0.2, 0.6)
    colour = torch.rand(3, generator=g, dtype=torch.float64) * 0.5
    f0 = _uniform(g, 0.04, 0.9)

    def f(wi, wo):
        a, s = _ggx_lobe(wi, wo, sharp, sharp)
        b, _ = _ggx_lobe(wi, wo, haze, haze)
        fresnel = f0 + (1 - f0) * (1 - s.cos_d) ** 5
        # The diffuse part gets what the specular layer leaves (1 - f0): albedo stays below 1.
        return (1 - f0) * colour / math.pi + fresnel * ((1 - weight) * a + weight * b)

    return AnalyticMaterial(f"two-lobes-{i:03d}", f, isotropic=True,
                            metadata={"family": "two_lobes", "alpha": (sharp, haze)})


def _clear_coat(g: torch.Generator, i: int) -> AnalyticMaterial:
    """A rough coloured base under a smooth dielectric coat (IOR 1.5): the base is attenuated by
    the coat's transmission in and out (Weidlich & Wilkie 2007, simplified without refraction)."""
    base = torch.rand(3, generator=g, dtype=torch.float64) * 0.7
    base_alpha = _log_uniform(g, 0.2, 0.5, 1)[0]
    coat_alpha = _log_uniform(g, 0.01, 0.06, 1)[0]

    def f(wi, wo):
        coat, s = _ggx_lobe(wi, wo, coat_alpha, coat_alpha)
        spec, _ = _ggx_lobe(wi, wo, base_alpha, base_alpha)
        transmit = (1 - dielectric_fresnel(s.cos_i, 1.5)) * (1 - dielectric_fresnel(s.cos_o, 1.5))
        under = base / math.pi + 0.3 * base * spec
        return transmit * under + dielectric_fresnel(s.cos_d, 1.5) * coat

    return AnalyticMaterial(f"clear-coat-{i:03d}", f, isotropic=True, metadata={"family": "clear_coat"})


def _sheen(g: torch.Generator, i: int) -> AnalyticMaterial:
    """Cloth: Lambertian plus the "Charlie" sheen distribution (Estevez & Kulla 2017) with the
    Neubelt & Pettineo 2013 visibility 1 / (4 (cos_i + cos_o - cos_i cos_o))."""
    colour = torch.rand(3, generator=g, dtype=torch.float64) * 0.6
    sheen = 0.3 + 0.7 * torch.rand(3, generator=g, dtype=torch.float64)
    r = _uniform(g, 0.3, 0.9)

    def f(wi, wo):
        s = _shading(wi, wo)
        sin_h = torch.sqrt((1 - s.cos_h**2).clamp_min(0.0))
        d = (2 + 1 / r) * sin_h ** (1 / r) / (2 * math.pi)
        vis = 1 / (4 * (s.cos_i + s.cos_o - s.cos_i * s.cos_o))
        return colour / math.pi + sheen * d * vis

    return AnalyticMaterial(f"sheen-{i:03d}", f, isotropic=True, metadata={"family": "sheen"})


def _retro(g: torch.Generator, i: int) -> AnalyticMaterial:
    """Retro-reflective paint: Lambertian plus a lobe around wo = wi (exp((wi.wo - 1) / s))."""
    colour = torch.rand(3, generator=g, dtype=torch.float64) * 0.5
    width = _log_uniform(g, 0.02, 0.1, 1)[0]
    strength = _uniform(g, 0.1, 0.5)  # the lobe's albedo is about strength * cos_i

    def f(wi, wo):
        back = (wi * wo).sum(-1, keepdim=True)
        lobe = torch.exp((back - 1) / width) / (2 * math.pi * width)
        return colour / math.pi + strength * lobe * torch.ones(3, dtype=wi.dtype)

    return AnalyticMaterial(f"retro-{i:03d}", f, isotropic=True, metadata={"family": "retro"})


def _oren_nayar(g: torch.Generator, i: int) -> AnalyticMaterial:
    """Rough diffuse: Oren & Nayar 1994 qualitative model (eq. 30) plus a faint GGX gloss."""
    colour = 0.2 + 0.7 * torch.rand(3, generator=g, dtype=torch.float64)
    sigma = _uniform(g, 0.3, 0.9)
    a = 1 - 0.5 * sigma**2 / (sigma**2 + 0.33)
    b = 0.45 * sigma**2 / (sigma**2 + 0.09)

    def f(wi, wo):
        ti = torch.acos(wi[:, 2:3].clamp(-1, 1))
        to = torch.acos(wo[:, 2:3].clamp(-1, 1))
        pi_ = torch.atan2(wi[:, 1:2], wi[:, 0:1])
        po = torch.atan2(wo[:, 1:2], wo[:, 0:1])
        alpha, beta = torch.maximum(ti, to), torch.minimum(ti, to)
        diffuse = colour / math.pi * (a + b * torch.cos(pi_ - po).clamp_min(0) * torch.sin(alpha) * torch.tan(beta))
        gloss, s = _ggx_lobe(wi, wo, 0.3, 0.3)
        return diffuse + 0.04 * gloss

    return AnalyticMaterial(f"oren-nayar-{i:03d}", f, isotropic=True, metadata={"family": "oren_nayar"})


ZOO_FAMILIES: dict[str, Callable[[torch.Generator, int], AnalyticMaterial]] = {
    "conductor": _conductor,
    "two_lobes": _two_lobes,
    "clear_coat": _clear_coat,
    "sheen": _sheen,
    "retro": _retro,
    "oren_nayar": _oren_nayar,
}


def synthetic_zoo(n_materials: int, seed: int, families: tuple[str, ...] | None = None) -> list[AnalyticMaterial]:
    """``n_materials`` zoo materials cycling through ``families`` (all by default), seeded."""
    families = families or tuple(ZOO_FAMILIES)
    unknown = [f for f in families if f not in ZOO_FAMILIES]
    if unknown:
        raise ValueError(f"unknown zoo families {unknown}; available: {list(ZOO_FAMILIES)}")
    g = torch.Generator().manual_seed(seed)
    return [ZOO_FAMILIES[families[i % len(families)]](g, i) for i in range(n_materials)]


def synthetic_ggx(n_materials: int, seed: int, noise_sigma: float = 0.1) -> list[AnalyticMaterial]:
    """The paper's random anisotropic GGX materials with multiplicative N(1, noise_sigma) noise."""
    from ..models import get_model

    model = get_model("ggx")
    g = torch.Generator().manual_seed(seed)
    out = []
    for i in range(n_materials):
        params = {
            "normal": torch.randn(2, generator=g, dtype=torch.float64).mul(0.05).clamp(-0.2, 0.2),
            "t_theta": torch.tensor([_uniform(g, -math.pi / 2, math.pi / 2)], dtype=torch.float64),
            "rho_d": torch.rand(3, generator=g, dtype=torch.float64) * 0.6,
            "rho_s": 0.2 + 0.8 * torch.rand(3, generator=g, dtype=torch.float64),
            "alpha_x": torch.tensor(_log_uniform(g, 0.03, 0.6, 1), dtype=torch.float64),
            "alpha_y": torch.tensor(_log_uniform(g, 0.03, 0.6, 1), dtype=torch.float64),
            "f0": torch.tensor([_uniform(g, 0.02, 1.0)], dtype=torch.float64),
        }

        def f(wi, wo, params=params):
            return model.evaluate(wi, wo, params)

        out.append(AnalyticMaterial(f"ggx-{i:03d}", f, isotropic=False, noise_sigma=noise_sigma,
                                    metadata={"family": "ggx", "params": {k: v.tolist() for k, v in params.items()}}))
    return out


def _uniform(g: torch.Generator, lo: float, hi: float) -> float:
    return lo + (hi - lo) * float(torch.rand(1, generator=g, dtype=torch.float64))


def _log_uniform(g: torch.Generator, lo: float, hi: float, n: int) -> list[float]:
    u = torch.rand(n, generator=g, dtype=torch.float64)
    return [float(v) for v in torch.exp(math.log(lo) + (math.log(hi) - math.log(lo)) * u)]
