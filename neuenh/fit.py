"""Fit new materials with a trained model: module weights frozen, per-material parameters free.

Two protocols (both optimise the analytical and latent parameters of every material, starting from
the paper's initial values; the loss is the training loss, ``train.log_l1``):

* ``paper`` — the paper's Sec. 5.1: RMSProp (alpha 0.9), learning rate 1e-3, 1000 epochs, batches
  of 100K samples.
* ``fast`` (default) — Adam, learning rate 0.05 with cosine decay to 1e-3 of it, 300 epochs.
  Measured on 1e5 measurements (bench/bench_core.py, docs/BENCHMARKS.md) it reaches the paper
  protocol's final loss tens of times sooner, for plain and enhanced GGX alike: the parameters are
  few and well scaled by the constrained mapping, so a large adaptive step is safe where RMSProp
  at 1e-3 crawls.

Works for plain analytical models (all-zero state) as well as enhanced ones.

**Starting points of an enhanced model** (``FitConfig.starts``, beyond the paper). The modules were
trained on materials whose analytical parameters had been fitted first, so the paper's start (range
means, latent 0.5) can leave a new material in a poor basin: on RGL paper_white it ends 20 % above
plain GGX's loss. With ``starts="analytical"`` (the default) the analytical model of the same graph
is fitted first; the enhanced model is then made to *imitate that fit* (all its parameters fitted to
the analytical fit's predictions at the same directions), from latent 0.5 and from the mean code of
the model's training materials when given. Each imitation, and the paper's start, then starts a fit
to the measurements, and each material keeps the one with the lowest *fit* loss (held-out samples
play no part). An imitation starts the enhanced model close to where the analytical model ended, so
it improves on the analytical fit wherever its modules allow. The imitations take a third of the
fit's epochs: in all, one analytical fit and about 3.7 enhanced ones (docs/RESULTS.md has the fit
times). ``"paper"`` keeps the paper's start alone. A plain analytical model always has one start.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Iterator, Literal

import torch

from .data.samples import Samples
from .graph import BRDFModel
from .materials import LATENT_INIT, MaterialTable
from .train import evaluate_loss, log_l1, predict


@dataclass(frozen=True)
class FitConfig:
    method: Literal["fast", "paper"] = "fast"
    epochs: int | None = None  # default: 300 (fast) or 1000 (paper)
    lr: float | None = None  # default: 0.05 (fast) or 1e-3 (paper)
    batch_size: int = 100_000
    starts: Literal["analytical", "paper"] = "analytical"  # see the module doc

    def __post_init__(self) -> None:
        if self.method not in ("fast", "paper"):
            raise ValueError(f"fit method must be 'fast' or 'paper', got {self.method!r}")
        if self.starts not in ("analytical", "paper"):
            raise ValueError(f"fit starts must be 'analytical' or 'paper', got {self.starts!r}")
        if (self.epochs is not None and self.epochs < 1) or (self.lr is not None and self.lr <= 0):
            raise ValueError(f"invalid fit config {self}")

    @property
    def resolved_epochs(self) -> int:
        return self.epochs or (300 if self.method == "fast" else 1000)

    @property
    def resolved_lr(self) -> float:
        return self.lr or (0.05 if self.method == "fast" else 1e-3)


@dataclass
class FitResult:
    materials: MaterialTable
    losses: list[float]  # per material, mean log-L1 on the fitted samples
    wall_s: float
    epochs: int
    trace: list[tuple[float, float]] = field(default_factory=list)  # (seconds, mean loss)

    @property
    def loss(self) -> float:
        return float(sum(self.losses) / len(self.losses))

    def report(self, model: BRDFModel, method: str, samples: Samples) -> dict:
        """The fit as plain data (``neuenh fit --json`` and ``POST /v1/jobs/{id}/fit``): per material
        its loss, sample count and fitted parameters (the latent code only if the model uses it)."""
        counts = torch.bincount(samples.material, minlength=len(self.materials)).tolist()
        return {
            "model": model.name, "state": model.state, "method": method, "epochs": self.epochs,
            "wall_s": round(self.wall_s, 3),
            "materials": [
                {"name": name, "loss": self.losses[i], "samples": counts[i],
                 "params": {k: [round(x, 6) for x in v.tolist()] for k, v in self.materials.as_params(i).items()
                            if k != "latent" or model.uses_latent}}
                for i, name in enumerate(self.materials.names)],
        }


@contextlib.contextmanager
def frozen(model: BRDFModel) -> Iterator[None]:
    """Module weights take no gradient inside the block (restored afterwards)."""
    saved = [(p, p.requires_grad) for p in model.parameters()]
    for p, _ in saved:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p, flag in saved:
            p.requires_grad_(flag)


def fit_materials(
    model: BRDFModel,
    samples: Samples,
    config: FitConfig = FitConfig(),
    *,
    seed: int = 0,
    trace_every: int = 0,
    trained: MaterialTable | None = None,
) -> FitResult:
    """Fit every material of ``samples`` with ``model`` frozen, from the starts ``config.starts``
    names (module doc); ``trained`` are the model's training materials (a bundle's ``materials``),
    whose mean latent code is one start. ``trace_every`` > 0 records the mean loss every that many
    epochs (an extra evaluation each time; for benchmarks), for the first start."""
    if len(samples) == 0:
        raise ValueError("no samples to fit")
    if config.starts == "paper" or not any(model.digits):
        return fit_from(model, samples, MaterialTable(model.specs, samples.names, model.latent_dim),
                        config, seed=seed, trace_every=trace_every)
    start = time.perf_counter()
    analytical = model.enhance("0" * len(model.positions), seed)
    base = fit_from(analytical, samples, MaterialTable(analytical.specs, samples.names, model.latent_dim),
                    config, seed=seed).materials
    with torch.no_grad():
        imitate = Samples(samples.wi, samples.wo, predict(analytical, base, samples, slice(None)).clamp_min(0.0),
                          samples.material, samples.names)
    latents = [torch.full_like(base.latent, LATENT_INIT)]
    if trained is not None and model.uses_latent and len(trained):
        latents.append(trained.latent.detach().mean(0, keepdim=True).expand_as(base.latent))
    starts = [MaterialTable(model.specs, samples.names, model.latent_dim)]  # the paper's
    imitation = dataclasses.replace(config, epochs=max(1, config.resolved_epochs // 3))  # a start, not the fit
    for latent in latents:
        like_analytical = MaterialTable(model.specs, samples.names, model.latent_dim,
                                        {k: v.detach().clone() for k, v in base.raw.items()}, latent.clone())
        starts.append(fit_from(model, imitate, like_analytical, imitation, seed=seed).materials)
    fits = [fit_from(model, samples, table, config, seed=seed, trace_every=trace_every if i == 0 else 0)
            for i, table in enumerate(starts)]
    best = [min(range(len(fits)), key=lambda f: fits[f].losses[i]) for i in range(len(samples.names))]
    raw = {k: torch.stack([fits[f].materials.raw[k].detach()[i] for i, f in enumerate(best)]) for k in base.raw}
    latent = torch.stack([fits[f].materials.latent.detach()[i] for i, f in enumerate(best)])
    materials = MaterialTable(model.specs, samples.names, model.latent_dim, raw, latent)
    losses = [fits[f].losses[i] for i, f in enumerate(best)]
    return FitResult(materials, losses, time.perf_counter() - start, fits[0].epochs, fits[0].trace)


def fit_from(
    model: BRDFModel,
    samples: Samples,
    start: MaterialTable,
    config: FitConfig = FitConfig(),
    *,
    seed: int = 0,
    trace_every: int = 0,
) -> FitResult:
    """One fit of every material of ``samples`` from the parameters ``start`` (modified in place
    and returned as the result's ``materials``), ``model`` frozen."""
    if len(samples) == 0:
        raise ValueError("no samples to fit")
    start_time = time.perf_counter()
    materials = start
    params = list(materials.parameters())
    epochs, lr = config.resolved_epochs, config.resolved_lr
    if config.method == "paper":
        optimizer: torch.optim.Optimizer = torch.optim.RMSprop(params, lr=lr, alpha=0.9)
        schedule = None
    else:
        optimizer = torch.optim.Adam(params, lr=lr)
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=epochs, eta_min=lr * 1e-3)
    generator = torch.Generator().manual_seed(seed)
    trace: list[tuple[float, float]] = []
    full_batch = len(samples) <= config.batch_size
    with frozen(model):
        for epoch in range(epochs):
            order = slice(None) if full_batch else torch.randperm(len(samples), generator=generator)
            for lo in range(0, len(samples), config.batch_size):
                index = order if full_batch else order[lo : lo + config.batch_size]
                loss = log_l1(predict(model, materials, samples, index), samples.f_r[index], samples.wi[index]).mean()
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
            if schedule is not None:
                schedule.step()
            if trace_every and (epoch % trace_every == 0 or epoch == epochs - 1):
                trace.append((time.perf_counter() - start_time, evaluate_loss(model, materials, samples)))
        losses = per_material_loss(model, materials, samples)
    return FitResult(materials, losses, time.perf_counter() - start_time, epochs, trace)


@torch.no_grad()
def per_material_loss(model: BRDFModel, materials: MaterialTable, samples: Samples) -> list[float]:
    """Mean log-L1 of each material over its samples (NaN for a material with none)."""
    sums = torch.zeros(len(samples.names), dtype=torch.float64)
    counts = torch.zeros(len(samples.names), dtype=torch.float64)
    for lo in range(0, len(samples), 200_000):
        index = slice(lo, lo + 200_000)
        loss = log_l1(predict(model, materials, samples, index), samples.f_r[index], samples.wi[index])
        sums.index_add_(0, samples.material[index], loss.double())
        counts.index_add_(0, samples.material[index], torch.ones_like(loss, dtype=torch.float64))
    return [float(s / c) if c else math.nan for s, c in zip(sums, counts)]
