"""Fit new materials with a trained model: module weights frozen, per-material parameters free.

Two protocols (both optimise the analytical and latent parameters of every material, starting from
the paper's initial values; the loss is the training loss, ``train.log_l1``):

* ``paper`` — the paper's Sec. 5.1: RMSProp (alpha 0.9), learning rate 1e-3, 1000 epochs, batches
  of 100K samples.
* ``fast`` (default) — a plain analytical model (all-zero state) by row-wise L-BFGS
  (``neuenh.lbfgs``) on a Charbonnier surrogate of the log-L1 (``SURROGATE_EPS``), from two starts
  (``fit_plain``): measured on the 8 RGL materials (docs/BENCHMARKS.md), GGX ends lower than 300 Adam
  epochs did on 7 and within 0.2 % on the eighth (chm_orange 0.142 -> 0.051: Adam had stalled). An enhanced
  model by Adam, learning rate 0.05 with cosine decay to 1e-3 of it, 300 epochs: its landscape is
  rough (L-BFGS stopped in poorer minima on 4 of 4 materials tried, 3-9 % above Adam). Every start
  of a fit runs *together*: the starts are stacked as extra rows of one material table
  (``fit_starts``, ``fit_best_start``), so one batch serves them all, and a multi-start Adam fit
  narrows to each material's best start after ``NARROW_AT`` of its epochs.

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
fit's epochs: in all, one analytical fit, one stacked run of the imitations and one stacked run of
the three starts, narrowed to each material's best after a quarter of the epochs (``NARROW_AT``;
docs/RESULTS.md has the fit times). ``"paper"`` keeps the paper's start alone. A plain analytical
model always has one start.
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
from .lbfgs import minimize_rows
from .train import evaluate_loss, log_l1, log_residual, predict


@dataclass(frozen=True)
class FitConfig:
    method: Literal["fast", "paper"] = "fast"
    # fast: at most this many L-BFGS iterations per phase (default 150); paper: epochs (default 1000)
    epochs: int | None = None
    lr: float | None = None  # paper only (default 1e-3)
    batch_size: int = 100_000
    starts: Literal["analytical", "paper"] = "analytical"  # see the module doc

    def __post_init__(self) -> None:
        if self.method not in ("fast", "paper"):
            raise ValueError(f"fit method must be 'fast' or 'paper', got {self.method!r}")
        if self.starts not in ("analytical", "paper"):
            raise ValueError(f"fit starts must be 'analytical' or 'paper', got {self.starts!r}")
        if (self.epochs is not None and self.epochs < 1) or (self.lr is not None and self.lr <= 0) \
                or self.batch_size < 1:
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
    epochs: int  # epochs run (Adam, RMSProp), or L-BFGS iterations (a plain model's fast fit)
    trace: list[tuple[float, float]] = field(default_factory=list)  # (seconds, mean loss)

    @property
    def loss(self) -> float:
        return float(sum(self.losses) / len(self.losses))

    def report(self, model: BRDFModel, method: str, samples: Samples) -> dict:
        """The fit as plain data (``neuenh fit --json`` and ``POST /v1/jobs/{id}/fit``): per material
        its loss, sample count and fitted record as the state reads it (``BRDFModel.used_params``,
        ``MaterialParams.to_json``: parameters, latent code, corrections, capacity, count)."""
        counts = torch.bincount(samples.material, minlength=len(self.materials)).tolist()
        return {
            "model": model.name, "state": model.state, "method": method, "epochs": self.epochs,
            "wall_s": round(self.wall_s, 3),
            "materials": [
                {"name": name, "loss": self.losses[i], "samples": counts[i],
                 **model.used_params(self.materials.as_params(i)).to_json(digits=6)}
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
    whose mean latent code is one start. ``trace_every`` > 0 (paper method) records the mean loss
    every that many epochs (an extra evaluation each time; for benchmarks), for the first start."""
    if len(samples) == 0:
        raise ValueError("no samples to fit")
    start = time.perf_counter()
    paper_start = MaterialTable(model.specs, samples.names, model.latent_dim)
    if not model.has_modules and config.method == "fast":
        result = fit_plain(model, samples, config, trace_every=trace_every)
        result.wall_s = time.perf_counter() - start
        return result
    if config.starts == "paper" or not model.has_modules:
        (result,) = fit_starts(model, samples, [paper_start], config, seed=seed, trace_every=trace_every)
        result.wall_s = time.perf_counter() - start
        return result
    analytical = model.enhance(model.analytical_state(), seed)
    if config.method == "fast":
        # The old protocol's base (Adam), not fit_plain's lower-loss one: the imitations start from
        # it, and from fit_plain's they failed more often (GGX + residual on ilm_solo_m_68: 0.062
        # against 0.023; the shipped model at 300 samples: ilm_solo_m_68 x4, vch_silk_blue +86 %;
        # docs/BENCHMARKS.md).
        table = MaterialTable(analytical.specs, samples.names, model.latent_dim)
        adam_rows(analytical, samples, table, config)
        base = FitResult(table, [], 0.0, config.resolved_epochs)
    else:
        (base,) = fit_starts(analytical, samples, [MaterialTable(analytical.specs, samples.names, model.latent_dim)],
                             config, seed=seed)
    with torch.no_grad():
        imitate = Samples(samples.wi, samples.wo,
                          predict(analytical, base.materials, samples, slice(None)).clamp_min(0.0),
                          samples.material, samples.names)
    latents = [torch.full_like(base.materials.latent, LATENT_INIT)]
    if trained is not None and model.uses_latent and len(trained):
        latents.append(trained.latent.detach().mean(0, keepdim=True).expand_as(base.materials.latent))
    like_analytical = [MaterialTable(model.specs, samples.names, model.latent_dim,
                                     {k: v.detach().clone() for k, v in base.materials.raw.items()}, latent.clone())
                       for latent in latents]
    imitation = dataclasses.replace(config, epochs=max(1, config.resolved_epochs // 3))  # a start, not the fit
    imitated = [r.materials for r in fit_starts(model, imitate, like_analytical, imitation, seed=seed)]
    result = fit_best_start(model, samples, [paper_start, *imitated], config, seed=seed, trace_every=trace_every)
    result.wall_s = time.perf_counter() - start
    return result


# Adam epochs before the second L-BFGS start of a plain model's fit (``fit_plain``).
PLAIN_WARMUP = 100


def fit_plain(model: BRDFModel, samples: Samples, config: FitConfig = FitConfig(), *,
              trace_every: int = 0) -> FitResult:
    """The fast fit of a plain analytical model: L-BFGS (``fit_rows``) from two starts stacked as
    rows of one table — the paper's start, and where ``PLAIN_WARMUP`` Adam epochs took it — each
    material keeping the lower loss. L-BFGS alone sometimes stops early in a poor basin (Ward on
    vch_silk_blue: 0.139 against Adam's 0.075), Adam alone stalls far from the optimum elsewhere
    (GGX on chm_orange: 0.142 against L-BFGS's 0.051); docs/BENCHMARKS.md has both."""
    start_time = time.perf_counter()
    warmed = MaterialTable(model.specs, samples.names, model.latent_dim)
    adam_rows(model, samples, warmed, dataclasses.replace(config, epochs=min(PLAIN_WARMUP, config.resolved_epochs)))
    direct, from_adam = fit_starts(model, samples, [MaterialTable(model.specs, samples.names, model.latent_dim),
                                                     warmed], config)
    materials, losses = _best_per_material(model, samples, [direct, from_adam])
    trace = [(time.perf_counter() - start_time, float(sum(losses) / len(losses)))] if trace_every else []
    return FitResult(materials, losses, time.perf_counter() - start_time, direct.epochs, trace)


def _best_per_material(model: BRDFModel, samples: Samples, fits: list[FitResult]) -> tuple[MaterialTable, list[float]]:
    """Each material's parameters and loss from the fit (of the same materials) where it ended lowest."""
    m = len(samples.names)
    best = [min(range(len(fits)), key=lambda f: fits[f].losses[i]) for i in range(m)]
    _, table = _stack(samples, [f.materials for f in fits])
    table = table.subset([f * m + i for i, f in enumerate(best)])
    materials = MaterialTable(model.specs, samples.names, model.latent_dim,
                              {k: v.detach() for k, v in table.raw.items()}, table.latent.detach())
    return materials, [fits[f].losses[i] for i, f in enumerate(best)]


def fit_starts(
    model: BRDFModel,
    samples: Samples,
    starts: list[MaterialTable],
    config: FitConfig = FitConfig(),
    *,
    seed: int = 0,
    trace_every: int = 0,
) -> list[FitResult]:
    """One fit of every material of ``samples`` from each table of ``starts`` (modified in place),
    ``model`` frozen. ``fast`` fits all starts together as the rows of one stacked table (an
    enhanced model by Adam, ``adam_rows``; a plain one by L-BFGS, ``fit_rows``); ``paper`` fits
    them one after another (``fit_from``)."""
    if config.method == "paper":
        return [fit_from(model, samples, table, config, seed=seed, trace_every=trace_every if i == 0 else 0)
                for i, table in enumerate(starts)]
    start_time = time.perf_counter()
    stacked, table = _stack(samples, starts)
    if model.has_modules:
        _, _, trace = adam_rows(model, stacked, table, config, trace_every=trace_every)
        iterations = config.resolved_epochs
    else:
        iterations = fit_rows(model, stacked, table, config)
        # L-BFGS is traced by its end point only (the time at which it had its final loss)
        trace = [(time.perf_counter() - start_time, evaluate_loss(model, table, stacked))] if trace_every else []
    losses = per_material_loss(model, table, stacked)
    wall_s = time.perf_counter() - start_time
    return [FitResult(_unstack(table, target, i), losses[i * len(target) : (i + 1) * len(target)], wall_s,
                      iterations, trace if i == 0 else [])
            for i, target in enumerate(starts)]


def fit_best_start(
    model: BRDFModel,
    samples: Samples,
    starts: list[MaterialTable],
    config: FitConfig = FitConfig(),
    *,
    seed: int = 0,
    trace_every: int = 0,
) -> FitResult:
    """Fit every material from each of ``starts`` and keep, per material, the start with the
    lowest fit loss. ``fast``: one stacked Adam run (``adam_rows``) that narrows to each material's
    best start after ``NARROW_AT`` of its epochs; ``paper``: every start to the end, one after
    another."""
    start_time = time.perf_counter()
    if config.method == "paper":
        fits = fit_starts(model, samples, starts, config, seed=seed, trace_every=trace_every)
        materials, losses = _best_per_material(model, samples, fits)
        trace = fits[0].trace
    else:
        stacked, table = _stack(samples, starts)
        table, _, trace = adam_rows(model, stacked, table, config, starts=len(starts), trace_every=trace_every)
        materials = MaterialTable(model.specs, samples.names, model.latent_dim,
                                  {k: v.detach() for k, v in table.raw.items()}, table.latent.detach())
        losses = per_material_loss(model, materials, samples)
    return FitResult(materials, losses, time.perf_counter() - start_time, config.resolved_epochs, trace)


def _stack(samples: Samples, starts: list[MaterialTable]) -> tuple[Samples, MaterialTable]:
    """k starts of the same m materials as one problem: a table of k*m rows (start i's materials at
    rows i*m..) and the samples repeated k times, block i pointing at start i's rows."""
    m, k = len(samples.names), len(starts)
    stacked = Samples(samples.wi.repeat(k, 1), samples.wo.repeat(k, 1), samples.f_r.repeat(k, 1),
                      torch.cat([samples.material + i * m for i in range(k)]),
                      tuple(f"{i}:{name}" for i in range(k) for name in samples.names))
    first = starts[0]
    table = MaterialTable(first.specs, stacked.names, first.latent_dim,
                          {name: torch.cat([t.raw[name].detach() for t in starts]) for name in first.specs.names},
                          torch.cat([t.latent.detach() for t in starts]))
    return stacked, table


def _unstack(table: MaterialTable, target: MaterialTable, i: int) -> MaterialTable:
    """Copy block ``i`` of a stacked ``table`` into ``target`` (same materials) and return it."""
    rows = slice(i * len(target), (i + 1) * len(target))
    with torch.no_grad():
        for name, raw in target.raw.items():
            raw.copy_(table.raw[name][rows])
        target.latent.copy_(table.latent[rows])
    return target


# The fast fit minimises a Charbonnier surrogate of the log-L1, sqrt(r^2 + eps^2) - eps per channel
# (Charbonnier et al. 1994): smooth, so L-BFGS's curvature pairs are meaningful, and within eps of
# |r| everywhere. Each phase starts from the last one's result with a smaller eps (the second is
# below the residuals that matter). The losses a fit reports are always the true log-L1.
SURROGATE_EPS = (1e-2, 1e-3)


class RowParameters:
    """A material table's free parameters as one (rows, d) matrix ``x``, for the row-wise
    optimisers: the analytical raw parameters in spec order, then the latent code if the model
    reads it. ``values(x)`` maps a matrix back to the physical values and latent the model takes."""

    def __init__(self, model: BRDFModel, table: MaterialTable):
        self.model, self.table = model, table
        self.names = list(model.specs.names)
        self.widths = [table.raw[name].shape[1] for name in self.names]
        if model.uses_latent:
            self.widths.append(table.latent_dim)

    def get(self) -> torch.Tensor:
        parts = [self.table.raw[name].detach() for name in self.names]
        return torch.cat(parts + ([self.table.latent.detach()] if self.model.uses_latent else []), dim=1)

    def set(self, x: torch.Tensor) -> None:
        parts = torch.split(x.detach().float(), self.widths, dim=1)
        with torch.no_grad():
            for name, part in zip(self.names, parts):
                self.table.raw[name].copy_(part)
            if self.model.uses_latent:
                self.table.latent.copy_(parts[-1])

    def values(self, x: torch.Tensor) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        parts = torch.split(x, self.widths, dim=1)
        values = {spec.name: spec.from_raw(part) for spec, part in zip(self.model.specs, parts)}
        return values, parts[-1] if self.model.uses_latent else self.table.latent.detach()[: len(x)]


def row_losses(model: BRDFModel, params: RowParameters, samples: Samples, x: torch.Tensor,
               per_sample=None, batch_size: int = 200_000) -> tuple[torch.Tensor, torch.Tensor]:
    """Each row's mean loss over its samples (R,) float64 and the gradient of their sum w.r.t.
    ``x`` (R, d): summing row means (not one global mean) makes a row's gradient independent of
    the rows stacked beside it. ``per_sample(residual (n, 3)) -> (n,)``, default the log-L1."""
    per_sample = per_sample or (lambda residual: residual.abs().mean(dim=1))
    x = x.detach().float().requires_grad_(True)
    rows = len(x)
    counts = torch.bincount(samples.material, minlength=rows).clamp_min(1).double()
    total = torch.zeros(rows, dtype=torch.float64)
    grad = torch.zeros_like(x)
    for lo in range(0, len(samples), batch_size):
        index = slice(lo, lo + batch_size)
        values, latent = params.values(x)
        material = samples.material[index]
        pred = model.forward_indexed(samples.wi[index], samples.wo[index], values, latent, material)
        loss = per_sample(log_residual(pred, samples.f_r[index], samples.wi[index])).double()
        row_loss = torch.zeros(rows, dtype=torch.float64).index_add_(0, material, loss) / counts
        (g,) = torch.autograd.grad(row_loss.sum(), x)
        grad += g
        total += row_loss.detach()
    return total, grad


def fit_rows(model: BRDFModel, samples: Samples, table: MaterialTable, config: FitConfig) -> int:
    """Fit every row of ``table`` to its samples with row-wise L-BFGS (``neuenh.lbfgs``), in place,
    on the Charbonnier surrogate's phases. Returns the iterations the slowest row ran."""
    params = RowParameters(model, table)

    def objective_for(eps: float):
        def charbonnier(residual: torch.Tensor) -> torch.Tensor:
            return ((residual * residual + eps * eps).sqrt() - eps).mean(dim=1)

        def objective(x: torch.Tensor, rows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            wanted = samples if bool(rows.all()) else samples.subset(torch.nonzero(rows[samples.material]).squeeze(1))
            loss, grad = row_losses(model, params, wanted, x, charbonnier, config.batch_size)
            return loss, grad.double()
        return objective

    x = params.get().double()
    iterations = 0
    with frozen(model):
        for eps in SURROGATE_EPS:
            result = minimize_rows(objective_for(eps), x, max_iter=config.resolved_epochs)
            x = result.x
            iterations += int(result.iterations.max())
    params.set(x)
    return iterations


# Adam's constants (Kingma & Ba 2015, Alg. 1; PyTorch's defaults).
ADAM_BETAS, ADAM_EPS = (0.9, 0.999), 1e-8
# A multi-start Adam fit keeps every start for this share of its epochs, then each material only its
# lowest-loss start (successive halving; Jamieson & Talwalkar 2016).
NARROW_AT = 0.25


def adam_rows(model: BRDFModel, samples: Samples, table: MaterialTable, config: FitConfig, *, starts: int = 1,
              trace_every: int = 0) -> tuple[MaterialTable, Samples, list[tuple[float, float]]]:
    """Adam over the rows of ``table`` (full batch; learning rate ``config.resolved_lr`` with
    cosine decay to 1e-3 of it over ``config.resolved_epochs``), every row on its own samples.

    ``starts`` > 1: ``table`` and ``samples`` stack that many starts of the same m materials
    (``_stack``); after ``NARROW_AT`` of the epochs each material keeps only its lowest-loss start,
    with its Adam moments, and the fit goes on over m rows. Returns the final table (modified in
    place when not narrowed), the samples it ends on and the trace (seconds, mean loss)."""
    start_time = time.perf_counter()
    params = RowParameters(model, table)
    x = params.get()
    moment1, moment2 = torch.zeros_like(x), torch.zeros_like(x)
    epochs, lr = config.resolved_epochs, config.resolved_lr
    narrow = int(NARROW_AT * epochs) if starts > 1 else -1
    trace: list[tuple[float, float]] = []
    with frozen(model):
        for epoch in range(epochs):
            loss, grad = row_losses(model, params, samples, x, batch_size=config.batch_size)
            if epoch == narrow:
                m = len(x) // starts
                best = loss.reshape(starts, m).argmin(0) * m + torch.arange(m)
                x, moment1, moment2, grad = x[best], moment1[best], moment2[best], grad[best]
                samples = samples.subset(torch.arange(len(samples) // starts))  # the first start's block
                samples = Samples(samples.wi, samples.wo, samples.f_r, samples.material,
                                  tuple(name.partition(":")[2] for name in samples.names[:m]))
                table = table.subset(range(m))
                params = RowParameters(model, table)
            step = epoch + 1
            rate = lr * (1e-3 + (1 - 1e-3) * 0.5 * (1 + math.cos(math.pi * epoch / epochs)))
            moment1.mul_(ADAM_BETAS[0]).add_(grad, alpha=1 - ADAM_BETAS[0])
            moment2.mul_(ADAM_BETAS[1]).addcmul_(grad, grad, value=1 - ADAM_BETAS[1])
            denom = (moment2 / (1 - ADAM_BETAS[1] ** step)).sqrt_().add_(ADAM_EPS)
            x = x - (rate / (1 - ADAM_BETAS[0] ** step)) * moment1 / denom
            if trace_every and (epoch % trace_every == 0 or epoch == epochs - 1):
                trace.append((time.perf_counter() - start_time, float(loss.mean())))
    params.set(x)
    return table, samples, trace


def fit_from(
    model: BRDFModel,
    samples: Samples,
    start: MaterialTable,
    config: FitConfig = FitConfig(),
    *,
    seed: int = 0,
    trace_every: int = 0,
) -> FitResult:
    """One fit by the paper's protocol (RMSProp, minibatches) of every material of ``samples`` from
    the parameters ``start`` (modified in place and returned as the result's ``materials``),
    ``model`` frozen."""
    if len(samples) == 0:
        raise ValueError("no samples to fit")
    start_time = time.perf_counter()
    materials = start
    params = list(materials.parameters())
    epochs = config.resolved_epochs
    optimizer = torch.optim.RMSprop(params, lr=config.resolved_lr, alpha=0.9)
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
