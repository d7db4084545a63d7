"""Compare contenders on one measured material: held-out log-L1, renders, image metrics, speed.

:func:`compare_material` draws a fit set and a test set of a material (``evaluate.draw_fit_test``),
renders its ground truth once, then for every contender (``contenders.Contender``): fits it on the
fit set, measures the paper's log-L1 on the test set (the training loss on the raw prediction, as
``evaluate.heldout_log_l1``), renders it with the *same* light samples as the truth (so the two
share their noise), and scores the render against the truth with SSIM and ΔE_ITP
(``render.metrics``). Two speed figures per contender: the render's wall time and
:func:`eval_throughput`, BRDF evaluations per second on a fixed batch.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Sequence

import torch

from .contenders import Contender, Directions
from ..data.directions import near_mirror_mask, sample_directions
from .heldout import draw_fit_test
from ..render import EnvironmentMap, ball_scene, render, sphere_scene
from ..render.envmaps import studio_environment
from ..render.metrics import delta_e_itp, ssim
from ..train import log_l1

__all__ = ["ContenderResult", "MaterialComparison", "RenderSetup", "compare_material", "eval_throughput"]


@dataclass(frozen=True)
class RenderSetup:
    """The comparison's scene under the procedural studio environment: the sphere on a ground plane
    (``render.ball_scene``, with shadows) or alone; metrics cover the sphere's pixels."""

    size: int = 96  # pixels per side
    samples_per_axis: int = 12  # light samples per pixel: its square
    seed: int = 0
    scene: str = "ball"  # or "sphere"

    def build_scene(self):
        if self.scene not in ("ball", "sphere"):
            raise ValueError(f"scene must be 'ball' or 'sphere', got {self.scene!r}")
        return ball_scene(self.size) if self.scene == "ball" else sphere_scene(self.size)

    def lights(self) -> EnvironmentMap:
        return EnvironmentMap(studio_environment(), samples_per_axis=self.samples_per_axis, seed=self.seed)


@dataclass
class ContenderResult:
    contender: str
    fit_loss: float
    heldout_log_l1: float
    fit_s: float
    params_per_material: int
    shared_weights: int
    ssim: float
    delta_e_itp: float  # ITU-R BT.2124 units (1.0 displayed at 100 cd/m²), mean over the sphere
    render_s: float
    rays: int  # (covered pixel, light sample) pairs of the render
    evals_per_s: float  # eval_throughput of the fitted BRDF
    heldout_near: float = float("nan")  # held-out log-L1 over the test pairs near the mirror direction
    heldout_away: float = float("nan")  # ... and over the others
    capacity: str | None = None  # the fit's capacity (a model with modules): params_per_material counts it

    def row(self) -> dict:
        return dict(self.__dict__)


@dataclass
class MaterialComparison:
    material: str
    n_fit: int
    n_test: int
    split: str
    results: list[ContenderResult]
    truth: torch.Tensor = field(repr=False)  # (H, W, 3) linear render
    images: dict[str, torch.Tensor] = field(repr=False)  # contender name -> render
    mask: torch.Tensor = field(repr=False)

    def by_name(self) -> dict[str, ContenderResult]:
        return {r.contender: r for r in self.results}


def _log_l1_rows(predict: Directions, wi, wo, f_r, batch: int = 100_000) -> torch.Tensor:
    """The loss of every test pair (n,) float64."""
    return torch.cat([log_l1(predict(wi[s], wo[s]), f_r[s], wi[s]).double()
                      for s in (slice(lo, lo + batch) for lo in range(0, len(wi), batch))])


def compare_material(material, contenders: Sequence[Contender], n_fit: int, n_test: int, seed: int = 0,
                     setup: RenderSetup = RenderSetup(), eval_pairs: int = 200_000) -> MaterialComparison:
    """Every contender fitted to ``material`` and measured (module doc); ``material`` is any
    measured source with ``evaluate`` and ``samples`` (RGL, MERL, NBRDF, analytical);
    ``eval_pairs`` direction pairs time the evaluation throughput."""
    fit, test, split = draw_fit_test(material, n_fit, n_test, seed)
    near = near_mirror_mask(test.wi.double(), test.wo.double())
    scene, lights = setup.build_scene(), setup.lights()
    truth = render(lambda wi, wo: material.evaluate(wi, wo).float(), scene, lights)
    rays = int(scene.mask.sum()) * setup.samples_per_axis ** 2
    results, images = [], {}
    for contender in contenders:
        fitted = contender.fit(fit, seed=seed)
        with torch.no_grad():
            losses = _log_l1_rows(fitted.predict, test.wi, test.wo, test.f_r)
        start = time.perf_counter()
        image = render(fitted.brdf, scene, lights)
        render_s = time.perf_counter() - start
        if not torch.isfinite(image).all():
            raise ValueError(f"{contender.name} on {material.name}: the render has non-finite pixels")
        images[contender.name] = image
        results.append(ContenderResult(
            contender=contender.name, fit_loss=fitted.fit_loss, heldout_log_l1=float(losses.mean()),
            heldout_near=float(losses[near].mean()) if near.any() else float("nan"),
            heldout_away=float(losses[~near].mean()) if (~near).any() else float("nan"), fit_s=fitted.fit_s,
            params_per_material=fitted.params_per_material, shared_weights=fitted.shared_weights,
            capacity=fitted.capacity,
            ssim=ssim(truth, image, mask=scene.mask), delta_e_itp=delta_e_itp(truth, image, mask=scene.mask),
            render_s=render_s, rays=rays, evals_per_s=eval_throughput(fitted.brdf, eval_pairs)))
    return MaterialComparison(material.name, len(fit), len(test), split, results, truth, images, scene.mask)


@torch.no_grad()
def eval_throughput(brdf: Directions, n: int = 200_000, repeats: int = 3, seed: int = 0) -> float:
    """BRDF evaluations per second of ``brdf`` on ``n`` Rusinkiewicz-uniform direction pairs
    (float32), the best of ``repeats`` timed runs after one warm-up run."""
    wi, wo = (t.float() for t in sample_directions(n, seed=seed, anisotropic=True))
    brdf(wi[:1000], wo[:1000])
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        brdf(wi, wo)
        best = min(best, time.perf_counter() - start)
    return n / best
