"""``render``: direct lighting of a scene by a BRDF, with the lights' fixed samples.

Directional lights are exact (one sample each, weight E). An environment map is estimated with

* ``sampling="mis"`` (the default): BRDF-independent multiple importance sampling — per pixel,
  N = n² fixed directions from a mixture of the map's luminance sampling, a cosine lobe and GGX
  reflection lobes about the mirror direction, weighted by the balance heuristic
  ``f_r L cos / Σ_k m_k p_k`` (``sampling.py``);
* ``sampling="light"``: the map's own samples only (``LightSamples.weight`` = L / (pdf · N)),

    L_o(x, wo) = Σ_k f_r(wi_k, wo) · L_k · max(cos θ_k, 0) / (pdf_k · N_light(k)).

Either way the directions and weights never depend on the BRDF, so every BRDF rendered with the
same lights shares the same noise. Directions below the shading horizon contribute 0 (they still
count in the estimator) and the BRDF is never asked about them. No visibility: a sphere does not
shadow itself (a convex object).

``brdf`` is any callable ``f(wi, wo) -> (n, 3)`` f_r without the cosine, in the local shading
frame (z = normal, x = tangent): a measured material's ``.evaluate`` (``load_measured``), an
analytical model with fixed parameters (``model_brdf(get_model("ggx"), params)``) or one
material of a bundle (``bundle_brdf(bundle, i)``).
"""

from __future__ import annotations

import math
from typing import Callable, Literal, Mapping, Sequence

import torch

from ..fit.result import model_for
from ..materials import MaterialParams
from .lights import DirectionalLight, EnvironmentMap, Light, gather
from .mis import DEFAULT_ALPHAS, mixture_density, mixture_directions, mixture_samples
from .scene import SphereScene

BRDF = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


def model_brdf(model, params: MaterialParams | Mapping[str, torch.Tensor], state: str | None = None) -> BRDF:
    """A ``BRDFModel`` with fixed parameters as a BRDF callable: its specialized evaluator
    (``BRDFModel.specialize``, equal to ``evaluate`` and several times faster), or ``evaluate``
    in another ``state`` of the model. A material fitted at an analytical capacity (``neuenh fit
    --capacity auto`` may choose one) is evaluated by that capacity's model (``neuenh.fit.model_for``),
    as its fit measured it."""
    if state is None or state == model.state:
        if isinstance(params, MaterialParams):
            model = model_for(model, params)
            params = model.used_params(params)
        return model.specialize(params)

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


def _check(f: torch.Tensor, n: int) -> None:
    if f.shape != (n, 3):
        raise ValueError(f"the BRDF must return (n, 3) f_r, got shape {tuple(f.shape)} for n = {n}")


@torch.no_grad()
def render(
    brdf: BRDF,
    scene: SphereScene,
    lights: Light | Sequence[Light],
    *,
    sampling: Literal["mis", "light"] = "mis",
    alphas: Sequence[float] = DEFAULT_ALPHAS,
    shares: Sequence[float] | None = None,
    dtype: torch.dtype = torch.float32,
    max_pairs: int = 1 << 18,
) -> torch.Tensor:
    """(H, W, 3) float64 linear radiance of ``scene`` lit by ``lights``; 0 outside the mask.

    Environment maps are sampled with ``sampling`` ("mis": the mixture of ``sampling.py`` with
    GGX lobes of roughnesses ``alphas`` and sample ``shares`` (env, cosine, one per roughness);
    "light": the map's own samples); directional lights are exact. The BRDF sees ``dtype``
    directions; at most ``max_pairs`` (pixel, sample) pairs at a time."""
    if sampling not in ("mis", "light"):
        raise ValueError(f"sampling must be 'mis' or 'light', got {sampling!r}")
    if isinstance(lights, (DirectionalLight, EnvironmentMap)):
        lights = [lights]
    lights = list(lights)
    if not lights:
        raise ValueError("no lights")
    if sampling == "light":
        return _render_light_samples(brdf, scene, lights, dtype=dtype, max_pairs=max_pairs)
    envs = [light for light in lights if isinstance(light, EnvironmentMap)]
    others = [light for light in lights if not isinstance(light, EnvironmentMap)]
    image = torch.zeros(*scene.shape, 3, dtype=torch.float64)
    if others:
        image = image + _render_light_samples(brdf, scene, others, dtype=dtype, max_pairs=max_pairs)
    for env in envs:
        image = image + _render_mis(brdf, scene, env, alphas=alphas, shares=shares, dtype=dtype, max_pairs=max_pairs)
    return image


def _render_mis(brdf: BRDF, scene: SphereScene, env: EnvironmentMap, *, alphas, shares, dtype,
                max_pairs: int) -> torch.Tensor:
    """One environment map by the mixture estimator of ``sampling.py``."""
    samples = mixture_samples(env, alphas, shares)

    def terms(frame: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # every strategy's direction for every pixel, local (c, K, 3) and world (frameᵀ · local)
        wi = mixture_directions(samples, frame, wo)
        world = torch.einsum("pji,pkj->pki", frame, wi)
        # L(wi) and the map's own density there, from the texel the direction falls in
        radiance, env_pdf = env.lookup(world.reshape(-1, 3))
        radiance, env_pdf = radiance.reshape(wi.shape), env_pdf.reshape(wi.shape[:2])
        # Σ_k m_k p_k(wi): every strategy's density at every direction (= N · p_mix)
        density = mixture_density(samples, wi, env_pdf, wo)
        # max(cos θ_i, 0) / (N p_mix) · L, the BRDF-independent part of each term
        return wi, (wi[..., 2:3] / density[..., None]) * radiance

    return _accumulate(brdf, scene, len(samples), terms, dtype=dtype, max_pairs=max_pairs)


def _render_light_samples(
    brdf: BRDF,
    scene: SphereScene,
    lights: Sequence[Light],
    *,
    dtype: torch.dtype,
    max_pairs: int,
) -> torch.Tensor:
    """The lights' own samples (directional lights exactly, maps by their luminance sampling)."""
    samples = gather(lights)

    def terms(frame: torch.Tensor, wo: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # every sample direction in every pixel's shading frame: (c, k, 3)
        wi = torch.einsum("pij,kj->pki", frame, samples.direction)
        # cos θ_i · the sample's estimator weight (radiance / pdf)
        return wi, wi[..., 2:3] * samples.weight

    return _accumulate(brdf, scene, len(samples), terms, dtype=dtype, max_pairs=max_pairs)


def _accumulate(brdf: BRDF, scene: SphereScene, k: int, terms, *, dtype: torch.dtype,
                max_pairs: int) -> torch.Tensor:
    """Σ over ``k`` samples of f_r(wi, wo) · weight per pixel, where ``terms(frame, wo)`` gives
    each chunk's local directions and BRDF-independent weights, both (c, k, 3). The sphere's pixels
    use ``brdf``; the ball scene's ground pixels its Lambertian albedo."""
    image = torch.zeros(*scene.shape, 3, dtype=torch.float64)
    image[scene.mask] = _shade(brdf, scene, scene.mask, False, k, terms, dtype, max_pairs)
    if scene.ground is not None and scene.ground.any():
        albedo = scene.ground_albedo / math.pi

        def ground(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
            return torch.full((wi.shape[0], 3), albedo, dtype=wi.dtype)

        image[scene.ground] = _shade(ground, scene, scene.ground, True, k, terms, dtype, max_pairs)
    return image


def _shade(brdf: BRDF, scene: SphereScene, pixels: torch.Tensor, on_ground: bool, k: int, terms,
           dtype: torch.dtype, max_pairs: int) -> torch.Tensor:
    """(P, 3) radiance of the ``pixels``. Pairs below the horizon or blocked (``scene.visible``)
    contribute 0 (the BRDF is not called there); at most ``max_pairs`` pairs at a time."""
    frames = scene.frames(pixels)  # (P, 3, 3) rows t, b, n
    wo = scene.wo_local[pixels]  # (P, 3)
    points = scene.position[pixels]
    out = torch.zeros(frames.shape[0], 3, dtype=torch.float64)
    chunk = max(1, max_pairs // k)
    for start in range(0, frames.shape[0], chunk):
        frame, wo_c = frames[start:start + chunk], wo[start:start + chunk]
        c = frame.shape[0]
        wi, weight = terms(frame, wo_c)
        lit = wi[..., 2] > 0  # below the horizon (or grazing exactly) a direction contributes 0 but counts
        if scene.shadowed:  # and so does a direction something blocks
            world = torch.einsum("pji,pkj->pki", frame, wi)
            lit &= scene.visible(points[start:start + c], world, torch.full((c,), on_ground))
        wi, weight = wi.reshape(c * k, 3), weight.reshape(c * k, 3)
        lit = torch.nonzero(lit.reshape(-1)).squeeze(1)  # flat (pixel, sample) pair indices
        # f_r at the lit pairs only, in the BRDF's dtype
        f = brdf(wi[lit].to(dtype), wo_c[lit // k].to(dtype)).to(torch.float64)
        _check(f, lit.shape[0])
        # f_r · weight per lit pair, zero for the others, summed over the samples
        contribution = torch.zeros(c * k, 3, dtype=torch.float64)
        contribution.index_copy_(0, lit, f * weight[lit])
        out[start:start + c] = contribution.reshape(c, k, 3).sum(dim=1)
    return out
