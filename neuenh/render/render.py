"""``render``: direct lighting of a scene by a BRDF, with the lights' fixed samples.

    L_o(x, wo) = Σ_k f_r(wi_k, wo) · L_k · max(cos θ_k, 0) / (pdf_k · N_light(k))

over the samples k of every light (``LightSamples.weight`` = L / (pdf · N), or E for a
directional light). Directions below the shading horizon contribute 0 and the BRDF is never
asked about them. No visibility: a sphere does not shadow itself (a convex object).

``brdf`` is any callable ``f(wi, wo) -> (n, 3)`` f_r without the cosine, in the local shading
frame (z = normal, x = tangent): a measured material's ``.evaluate`` (``load_measured``), an
analytical model with fixed parameters (``model_brdf(get_model("ggx"), params)``) or one
material of a bundle (``bundle_brdf(bundle, i)``).
"""

from __future__ import annotations

from typing import Callable, Mapping, Sequence

import torch

from .lights import Light, gather
from .scene import SphereScene

BRDF = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def model_brdf(model, params: Mapping[str, torch.Tensor], state: str | None = None) -> BRDF:
    """A ``BRDFModel`` with fixed parameters as a BRDF callable."""

    def f(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        return model.evaluate(wi, wo, params, state=state)

    return f


def bundle_brdf(bundle, material: int | str) -> BRDF:
    """Material ``material`` (index or name) of a bundle (``neuenh.checkpoint.Bundle``)."""
    if bundle.materials is None:
        raise ValueError("this bundle carries no materials; fit one first (neuenh fit)")
    index = material
    if isinstance(material, str):
        names = list(bundle.materials.names)
        if material not in names:
            raise ValueError(f"no material {material!r} in the bundle; it has {names}")
        index = names.index(material)
    return model_brdf(bundle.model, bundle.materials.as_params(index))


@torch.no_grad()
def render(
    brdf: BRDF,
    scene: SphereScene,
    lights: Light | Sequence[Light],
    *,
    dtype: torch.dtype = torch.float32,
    max_pairs: int = 1 << 18,
) -> torch.Tensor:
    """(H, W, 3) float64 linear radiance of ``scene`` lit by ``lights``; 0 outside the mask.

    The BRDF sees ``dtype`` directions; at most ``max_pairs`` (pixel, sample) pairs at a time."""
    samples = gather(lights)
    frames = scene.frames()  # (P, 3, 3) rows t, b, n
    wo = scene.wo_local[scene.mask]  # (P, 3)
    k = len(samples)
    out = torch.zeros(frames.shape[0], 3, dtype=torch.float64)
    chunk = max(1, max_pairs // k)
    for start in range(0, frames.shape[0], chunk):
        frame = frames[start:start + chunk]
        # every sample direction in every pixel's shading frame: (c, k, 3)
        wi = torch.einsum("pij,kj->pki", frame, samples.direction)
        c = frame.shape[0]
        # cos θ_i = wi.z; below the horizon (or grazing exactly) contributes nothing
        wi = wi.reshape(c * k, 3)
        lit = torch.nonzero(wi[:, 2] > 0).squeeze(1)  # flat (pixel, sample) pair indices
        pixel, sample = lit // k, lit % k
        wi_lit = wi[lit]
        # f_r at the lit pairs only, in the BRDF's dtype
        f = brdf(wi_lit.to(dtype), wo[start + pixel].to(dtype)).to(torch.float64)
        if f.shape != (lit.shape[0], 3):
            raise ValueError(f"the BRDF must return (n, 3) f_r, got shape {tuple(f.shape)} for n = {lit.shape[0]}")
        # f_r · cos θ_i · weight per lit pair, zero for the others, summed over the samples
        contribution = torch.zeros(c * k, 3, dtype=torch.float64)
        contribution.index_copy_(0, lit, f * wi_lit[:, 2:3] * samples.weight[sample])
        out[start:start + c] = contribution.reshape(c, k, 3).sum(dim=1)
    image = torch.zeros(*scene.shape, 3, dtype=torch.float64)
    image[scene.mask] = out
    return image
