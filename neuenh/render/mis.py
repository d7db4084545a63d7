"""BRDF-independent multiple importance sampling of an environment map ("mis", the default).

Sampling the light alone (``render(..., sampling="light")``) hits a narrow glossy lobe only where
one of the map's few sample directions happens to fall near the mirror direction, so a glossy
sphere shows each sample as its own small highlight. Here every pixel draws its N = n² directions
from a fixed **mixture** of strategies, none of which depends on the BRDF being rendered — so a
ground truth and a model still see exactly the same directions and weights (shared noise):

* ``env``: the map's luminance × solid-angle sampling (``EnvironmentMap.sample_directions``),
  the same world directions for every pixel; pdf ``EnvironmentMap.pdf``;
* ``cosine``: cosine-weighted hemisphere around the pixel's normal (Malley's method), the same
  local directions for every pixel; pdf ``max(cos θ, 0) / π``;
* ``ggx α`` for a few fixed roughnesses: a half vector ``h`` drawn from the isotropic GGX
  distribution of normals, ``p(h) = D_α(h) cos θ_h`` (Walter et al. 2007, eq. 35-36), reflected:
  ``wi = 2 (wo·h) h - wo``, a lobe around the mirror direction of the pixel's ``wo``; pdf
  ``D_α(h) cos θ_h / (4 |wo·h|)`` (the Jacobian of h -> wi), with ``h`` the half vector of
  (wi, wo) taken in the upper hemisphere. Over the whole sphere of ``wi`` it integrates to 1
  (h -> wi is one-to-one from the upper hemisphere of h); reflections below the horizon are drawn
  too and simply contribute 0.

Strategy k gets ``m_k`` of the N samples (``m_k ≈ c_k N`` for the fixed shares ``c_k``, summing
to N exactly), stratified on its own: the unit square is cut into ``m_k`` equal-area cells (rows
of heights ∝ their cell counts) each holding one jittered point, drawn once from a seeded
generator and cached on the map. With deterministic counts the balance heuristic gives the
multi-sample MIS estimator (Veach 1997, Sec. 9.2)

    L_o(wo) = Σ_j f_r(wi_j, wo) · L(wi_j) · max(cos θ_j, 0) / Σ_k m_k p_k(wi_j),

i.e. ``(1/N) Σ_j f L cos / p_mix`` with ``p_mix = Σ_k (m_k / N) p_k``: unbiased whenever every
direction where ``f L cos ≠ 0`` has ``p_mix > 0`` (the cosine strategy covers the hemisphere).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch

DEFAULT_ALPHAS = (0.02, 0.08, 0.3)
# shares of the samples: env, cosine, then one per GGX roughness
DEFAULT_SHARES = (0.3, 0.2, 0.5 / 3, 0.5 / 3, 0.5 / 3)
_EPS = 1e-300


def sample_counts(total: int, shares: Sequence[float]) -> list[int]:
    """Integer sample counts proportional to ``shares`` summing to ``total`` (largest remainder)."""
    shares = torch.as_tensor(shares, dtype=torch.float64)
    if (shares < 0).any() or float(shares.sum()) <= 0:
        raise ValueError(f"shares must be non-negative with a positive sum, got {shares.tolist()}")
    exact = shares / shares.sum() * total
    counts = exact.floor().long()
    order = torch.argsort(exact - counts, descending=True, stable=True)
    counts[order[: total - int(counts.sum())]] += 1
    return counts.tolist()


def stratified_unit_square(m: int, generator: torch.Generator) -> torch.Tensor:
    """(m, 2) points, one jittered point in each of m equal-area cells of the unit square.

    ``a = ⌊√m⌋`` rows; row i holds ``b_i`` cells (m split as evenly as possible) and has height
    ``b_i / m``, so every cell has area 1/m (equal strata: the plain average stays unbiased)."""
    if m == 0:
        return torch.zeros(0, 2, dtype=torch.float64)
    a = max(1, math.isqrt(m))
    b = torch.full((a,), m // a, dtype=torch.long)
    b[: m % a] += 1
    start = torch.cat([torch.zeros(1, dtype=torch.long), b.cumsum(0)[:-1]])  # first cell of each row
    row = torch.repeat_interleave(torch.arange(a), b)
    col = torch.arange(m) - start[row]
    jitter = torch.rand(m, 2, generator=generator, dtype=torch.float64)
    bf = b[row].to(torch.float64)
    u1 = (start[row].to(torch.float64) + jitter[:, 0] * bf) / m  # row i spans [start_i, start_i + b_i) / m
    u2 = (col.to(torch.float64) + jitter[:, 1]) / bf
    return torch.stack([u1, u2], dim=-1).clamp(0.0, 1.0 - 1e-12)


def cosine_directions(u: torch.Tensor) -> torch.Tensor:
    """Cosine-weighted local directions (z up) of unit-square points: cos θ = √(1 - u₁)."""
    cos_t = torch.sqrt(1.0 - u[:, 0])
    sin_t = torch.sqrt(u[:, 0])
    phi = 2 * math.pi * u[:, 1]
    return torch.stack([sin_t * torch.cos(phi), sin_t * torch.sin(phi), cos_t], dim=-1)


def ggx_half_vectors(u: torch.Tensor, alpha: float) -> torch.Tensor:
    """Local half vectors drawn from D_α(h) cos θ_h: cos² θ_h = (1 - u₁) / (1 + (α² - 1) u₁)."""
    cos2 = (1.0 - u[:, 0]) / (1.0 + (alpha * alpha - 1.0) * u[:, 0])
    cos_t = torch.sqrt(cos2.clamp(0.0, 1.0))
    sin_t = torch.sqrt((1.0 - cos2).clamp(0.0, 1.0))
    phi = 2 * math.pi * u[:, 1]
    return torch.stack([sin_t * torch.cos(phi), sin_t * torch.sin(phi), cos_t], dim=-1)


def ggx_ndf_cos(cos_h: torch.Tensor, alpha: float) -> torch.Tensor:
    """D_α(h) cos θ_h, the density of the half vector: α² cos / (π ((α² - 1) cos² + 1)²)."""
    a2 = alpha * alpha
    return a2 * cos_h / (math.pi * ((a2 - 1.0) * cos_h * cos_h + 1.0) ** 2)


def cosine_pdf(wi: torch.Tensor) -> torch.Tensor:
    """Solid-angle density of ``cosine_directions`` at local directions (…, 3)."""
    return wi[..., 2].clamp_min(0.0) / math.pi


def ggx_reflection_pdf(wi: torch.Tensor, wo: torch.Tensor, alpha: float) -> torch.Tensor:
    """Solid-angle density of ``reflect(wo, h)``, h ~ D_α cos, at local directions wi (…, 3) for
    local wo (broadcast): D_α(h) cos θ_h / (4 |wo·h|), h = ±(wi + wo)/|wi + wo| with h_z ≥ 0."""
    h = wi + wo
    h = h / torch.linalg.vector_norm(h, dim=-1, keepdim=True).clamp_min(1e-12)
    h = torch.where(h[..., 2:3] < 0, -h, h)
    return ggx_ndf_cos(h[..., 2], alpha) / (4.0 * (h * wo).sum(-1).abs().clamp_min(1e-12))


def reflect(wo: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
    """wi = 2 (wo·h) h - wo (broadcast)."""
    return 2.0 * (wo * h).sum(-1, keepdim=True) * h - wo


@dataclass(frozen=True)
class MixtureSamples:
    """The fixed, BRDF-independent unit-square samples of every strategy of one map.

    ``env_direction`` (m_env, 3) world directions, ``env_radiance`` (m_env, 3); ``cosine`` (m_cos, 3)
    local directions; ``half_vectors[i]`` (m_i, 3) local half vectors of ``alphas[i]``; ``counts``
    the m_k in the order env, cosine, alphas."""

    env_direction: torch.Tensor
    env_radiance: torch.Tensor
    cosine: torch.Tensor
    half_vectors: tuple[torch.Tensor, ...]
    alphas: tuple[float, ...]
    counts: tuple[int, ...]

    def __len__(self) -> int:
        return sum(self.counts)


def mixture_samples(env, alphas: Sequence[float] = DEFAULT_ALPHAS,
                    shares: Sequence[float] | None = None) -> MixtureSamples:
    """The map's mixture samples (``env.samples_per_axis``² in all, from ``env.seed``), drawn once
    and cached on the map."""
    alphas = tuple(float(a) for a in alphas)
    if any(not (0 < a <= 1) for a in alphas):
        raise ValueError(f"GGX roughnesses must lie in (0, 1], got {alphas}")
    if shares is None:
        shares = DEFAULT_SHARES if alphas == DEFAULT_ALPHAS else (0.3, 0.2) + (0.5 / max(1, len(alphas)),) * len(alphas)
    shares = tuple(float(s) for s in shares)
    if len(shares) != 2 + len(alphas):
        raise ValueError(f"need {2 + len(alphas)} shares (env, cosine, one per roughness), got {len(shares)}")
    key = ("mis", alphas, shares)
    if key in env._cache:
        return env._cache[key]
    counts = sample_counts(env.samples_per_axis ** 2, shares)
    if counts[1] == 0:
        raise ValueError("the cosine strategy needs at least one sample (it covers the hemisphere)")
    # one seeded generator per map, the strategies drawn in a fixed order
    generator = torch.Generator().manual_seed(env.seed + 0x5EED)
    u = [stratified_unit_square(m, generator) for m in counts]
    direction, _, radiance = env.sample_directions(u[0])
    result = MixtureSamples(direction, radiance, cosine_directions(u[1]),
                            tuple(ggx_half_vectors(ui, a) for ui, a in zip(u[2:], alphas)), alphas, tuple(counts))
    env._cache[key] = result
    return result


def mixture_directions(samples: MixtureSamples, frame: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """(c, K, 3) local directions of c pixels (shading frames (c, 3, 3), local ``wo`` (c, 3))."""
    c = frame.shape[0]
    parts = [torch.einsum("pij,kj->pki", frame, samples.env_direction),  # world -> local
             samples.cosine.expand(c, -1, -1)]
    for h in samples.half_vectors:
        parts.append(reflect(wo[:, None, :], h[None, :, :]))  # (c, m, 3)
    return torch.cat(parts, dim=1)


def mixture_density(samples: MixtureSamples, wi: torch.Tensor, env_pdf: torch.Tensor,
                    wo: torch.Tensor) -> torch.Tensor:
    """Σ_k m_k p_k(wi) at local directions ``wi`` (c, K, 3) for local ``wo`` (c, 3), given the
    map's density ``env_pdf`` (c, K) at the same directions: N times the mixture's density."""
    counts = samples.counts
    # the map's density (looked up by the caller at the world direction)
    total = counts[0] * env_pdf
    # the cosine lobe about the normal
    total = total + counts[1] * cosine_pdf(wi)
    # every GGX reflection lobe about the mirror direction of wo
    for m, alpha in zip(counts[2:], samples.alphas):
        if m:
            total = total + m * ggx_reflection_pdf(wi, wo[:, None, :], alpha)
    return total
