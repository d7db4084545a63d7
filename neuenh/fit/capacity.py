"""Adaptive capacity: per-material corrections of module weights, and a fit that chooses how much
freedom each material's data supports.

Beyond its analytical parameters and latent code, a material may carry *corrections*: deltas of the
shared module weights that are its own (``kernel.LayerCorrection``), pulled towards the shared
weights by an L2 prior (``kernel.RowSpace.prior``, relative to each corrected layer's size). A
*capacity* names which corrections are free:

==============  =================================================================================
``original``    the model the search started from (every position at its original term: plain GGX)
``analytical``  the analytical model of the same graph (modules back to their original terms)
``latent``      the latent code and analytical parameters (the paper's fit)
``last-layer``  + the last layer of every module, dense
``low-rank``    + the last layer dense and a rank-2 delta of every other layer
``rank-8``      + the last layer dense and a rank-8 delta of every other layer
``full``        + every layer of every module, dense
==============  =================================================================================

``Adaptive`` chooses, per material, a candidate (capacity and prior strength) by its validation
loss on its own fit data, then fits that candidate alone to all the samples:

1. *validation*, on at most ``validation_cap`` of a material's samples: they are split in folds; a
   candidate is fitted to the samples outside a held-out fold and scored on it (by default one fold
   of three: a single validation split; k-fold cross-validation when ``validation_folds`` says so).
   Every candidate and fold is a row of one batch per stage, each row on a grid holding only its own
   fit samples (``Rows.as_problems``):
   each analytical candidate one L-BFGS run (``PlainLBFGS``), the latent one one stacked multi-start
   Adam run (``LatentAdam``), every candidate with corrections one Adam run from those latent fits.
   The choice is the candidate with the fewest parameters per material among those whose
   validation loss is above the lowest by at most ``standard_errors`` standard errors of that gap:
   by default 0, the lowest validation loss; 1 is the one-standard-error rule of Hastie, Tibshirani
   & Friedman, *The Elements of Statistical Learning*, 2nd ed. 2009, §7.10, on paired differences
   (every candidate is scored on the same held-out samples, so the gap's error is the spread of the
   per-sample differences over the square root of their count), which keeps simpler models on few
   samples — better at 100 samples, worse at the user's 3,000 near the mirror (docs/BENCHMARKS.md,
   "`--capacity auto`: the model the search started from, and the one-standard-error rule").
2. *the fit to all the samples*, at each material's chosen candidate only: ``PlainLBFGS`` for
   ``original`` and ``analytical`` (the analytical-only fits), ``LatentAdam`` for ``latent`` (the
   latent fit), and for corrections the same Adam run started from the candidate's fit of the first
   fold's other samples (a start near the end, instead of a second latent fit to start from).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable, ClassVar

import torch

from ..capacities import ANALYTICAL_CAPACITIES
from ..data.samples import Samples
from ..materials import MaterialTable
from ..model import BRDFModel
from .jit import KERNELS, row_kernel
from .kernel import LayerCorrection, RowKernel, RowSpace, frozen
from .layout import fold_masks
from .optim import Adam, AdamResult, adam_rows, evaluate_rows
from .protocols import FitProtocol, LatentAdam, PlainLBFGS, Rows, _check, paper_start
from .result import FitResult, analytical_model


def _low_rank(rank: int) -> Callable[[BRDFModel], list[LayerCorrection]]:
    """The last layer of every module dense, a rank-``rank`` delta of every other layer."""
    return lambda model: [LayerCorrection(p, i, None if i == len(m.layers) - 1 else rank)
                          for p, m in model.neural.items() for i in range(len(m.layers))]


CAPACITIES: dict[str, Callable[[BRDFModel], list[LayerCorrection]] | None] = {
    **{capacity: None for capacity in ANALYTICAL_CAPACITIES},  # an analytical model in the modules' place
    "latent": lambda model: [],
    "last-layer": lambda model: [LayerCorrection(p, len(m.layers) - 1) for p, m in model.neural.items()],
    "low-rank": _low_rank(2),
    "rank-8": _low_rank(8),
    "full": lambda model: [LayerCorrection(p, i) for p, m in model.neural.items() for i in range(len(m.layers))],
}


def capacity_space(model: BRDFModel, capacity: str, seed: int = 0) -> tuple[BRDFModel, RowSpace]:
    """The model a capacity evaluates (an analytical model for ``ANALYTICAL_CAPACITIES``) and its rows' space."""
    if capacity not in CAPACITIES:
        raise ValueError(f"unknown capacity {capacity!r} (capacities: {', '.join(CAPACITIES)})")
    if CAPACITIES[capacity] is None:
        analytical = analytical_model(model, capacity, seed)
        return analytical, RowSpace(analytical)
    return model, RowSpace(model, CAPACITIES[capacity](model))


@dataclass
class Fitted:
    """One material's fit at its chosen capacity: the model that evaluates it (an analytical
    model for an analytical capacity), its row ``x`` (``space.dim``,) and its mean log-L1 on its samples."""

    capacity: str
    prior: float | None
    model: BRDFModel
    space: RowSpace
    x: torch.Tensor
    loss: float


@dataclass
class Validation:
    """Every candidate's validation loss per material, (m,) float64, and its losses on each
    held-out sample, (m, samples) float64, where ``held_out`` (m, samples) marks the real ones (the
    same samples, in the same order, for every candidate: the folds side by side)."""

    loss: dict[tuple[str, float | None], torch.Tensor]
    per_sample: dict[tuple[str, float | None], torch.Tensor]
    held_out: torch.Tensor
    # each analytical capacity's fit of the first fold's other samples, (m, its RowSpace dim)
    analytical_fits: dict[str, torch.Tensor] = field(default_factory=dict)


def gap_errors(per_sample: torch.Tensor, held_out: torch.Tensor) -> torch.Tensor:
    """(candidates, m) the standard error of each candidate's gap to the one of lowest mean loss,
    from ``per_sample`` (candidates, m, samples) losses on the same ``held_out`` (m, samples)
    samples: the sample standard deviation of the per-sample differences over the root of their count."""
    per_sample = torch.where(held_out, per_sample, 0.0)  # a padding slot's loss may be anything
    weight = held_out.double()
    count = weight.sum(1)
    mean = (per_sample * weight).sum(2) / count.clamp_min(1)
    best = mean.argmin(0)
    gap = per_sample - per_sample[best, torch.arange(per_sample.shape[1])]
    gap_mean = (gap * weight).sum(2, keepdim=True) / count.clamp_min(1)[:, None]
    variance = ((gap - gap_mean).square() * weight).sum(2) / (count - 1).clamp_min(1)
    return (variance / count.clamp_min(1)).sqrt()


def simplest_within(loss: torch.Tensor, gap_error: torch.Tensor, n_params: list[tuple[int, float]],
                    standard_errors: float) -> list[int]:
    """The one-standard-error rule (module doc): per material (column of ``loss``, (candidates, m)),
    among the candidates whose loss is above the lowest by at most ``standard_errors`` times
    ``gap_error`` (the standard error of that gap, (candidates, m)), the first in the order of
    ``n_params`` (a sort key per candidate: parameters per material, then what breaks ties; equal
    keys keep the candidates' order)."""
    within = loss - loss.min(0).values <= standard_errors * gap_error
    simplest_first = sorted(range(len(n_params)), key=lambda c: n_params[c])
    return [next(c for c in simplest_first if within[c, i]) for i in range(loss.shape[1])]


def label(capacity: str, prior: float | None) -> str:
    """A candidate's name in fit details: the capacity, ``@strength`` when it has a prior."""
    return capacity + ("" if prior is None else f"@{prior:g}")


@dataclass(frozen=True)
class Adaptive(FitProtocol):
    """Capacity and prior strength per material by cross-validation on its own fit data (module doc).

    ``capacities``: the candidates, from ``CAPACITIES``; ``priors``: the prior strengths tried for
    each capacity with corrections. The samples are split in ``folds`` folds; the first
    ``validation_folds`` are held out in turn (1: a single validation split of 1/``folds`` of the
    samples; ``folds``: k-fold cross-validation), every candidate fitted to the rest and scored on
    them. Then each material is fitted to all its samples at its chosen candidate only.

    Budgets: the analytical candidates by ``PlainLBFGS`` (``lbfgs_iterations``), the latent one by
    ``LatentAdam`` (``latent_epochs``, from ``latent_starts``), corrections by ``correction_epochs``
    Adam epochs at lr ``correction_lr`` from the latent fit of the same samples. A single candidate
    is fitted without validation. ``standard_errors``: how far above the lowest validation loss a
    simpler candidate may be and still be chosen (module doc; 0: the lowest, 1: the one-SE rule).
    The model's ``encoder`` gives it no start: each fold's latent fit would need the encoder's
    prediction from that fold's samples alone (not measured; its starts are ``LatentAdam``'s own).

    A material with more than ``validation_cap`` samples (None: no cap) chooses on a seeded random
    ``validation_cap`` of them (``Samples.at_most``) and is then fitted to all of them: at 100,000
    samples the choice costs what it costs at 20,000, and the fit of all the samples still learns
    from every one (the whole fit 0.21× the time, held-out error the same within 2.4 %: docs/BENCHMARKS.md,
    "The adaptive fit of many samples chooses on 20,000 of them")."""

    name: ClassVar[str] = "adaptive"
    # "original" so that few samples can keep the model the search started from (plain GGX): at 100
    # samples the modules' capacities lost to it (docs/BENCHMARKS.md, "`--capacity auto`: the model the
    # search started from, and the one-standard-error rule"). Of equal sizes the first is preferred: a
    # model without alternatives has one analytical model, named "analytical".
    # "rank-8" beside "low-rank" (not instead): on the training sources' materials, many samples chose it and
    # fitted better, while at 1,000 near the mirror rank 2 alone still won on several (docs/BENCHMARKS.md,
    # "`--capacity auto` with a rank-8 candidate").
    capacities: tuple[str, ...] = ("analytical", "original", "latent", "last-layer", "low-rank", "rank-8")
    priors: tuple[float, ...] = (1e-3, 1e-2)
    folds: int = 3
    validation_folds: int = 1
    latent_epochs: int = 300
    latent_starts: str = "analytical"
    lbfgs_iterations: int = 300
    correction_epochs: int = 150
    correction_lr: float = 0.01
    standard_errors: float = 0.0
    validation_cap: int | None = 20_000
    kernel: str = "torch"  # neuenh.fit.jit.KERNELS: every stage's rows (the latent ones: ``latent_kernel`` if set)
    latent_narrow_at: float = 0.25  # its latent fits' ``LatentAdam.narrow_at`` (``latent_protocol``)
    latent_kernel: str | None = None  # its latent fits' kernel (``latent_protocol``); None: ``kernel``
    latent_coarse_slots: int | None = None  # its latent fits' ``LatentAdam.coarse_slots`` (``latent_protocol``)

    def __post_init__(self) -> None:
        unknown = [c for c in self.capacities if c not in CAPACITIES]
        if unknown or not self.capacities:
            raise ValueError(f"unknown capacities {unknown} (known: {', '.join(CAPACITIES)})")
        if (self.folds < 2 or not 1 <= self.validation_folds <= self.folds or not self.priors
                or any(p < 0 for p in self.priors) or self.correction_epochs < 1 or self.standard_errors < 0
                or (self.validation_cap is not None and self.validation_cap < self.folds) or self.kernel not in KERNELS
                or self.latent_kernel not in (None, *KERNELS) or not 0 <= self.latent_narrow_at < 1
                or (self.latent_coarse_slots is not None and self.latent_coarse_slots < 1)):
            raise ValueError(f"invalid adaptive protocol {self}")

    @property
    def budget_epochs(self) -> int:
        return self.latent_epochs

    def work(self, samples: Samples) -> int:
        """The latent epochs of each validation fold over at most ``validation_cap`` of each
        material's samples, then of the fit to all of them (a single candidate: that fit alone). The
        candidates with corrections are not counted apart: their Adam epochs over the same samples are
        half as many, and a 10,000-sample fit takes ~2.1x a latent fit's time (docs/RESULTS.md), which
        the two latent passes stand for."""
        validation = 0 if len(self.grid) == 1 else self.validation_folds * samples.count_at_most(self.validation_cap)
        return (validation + len(samples)) * self.latent_epochs

    @property
    def grid(self) -> list[tuple[str, float | None]]:
        return [(c, p) for c in self.capacities for p in ((None,) if CAPACITIES[c] is None or c == "latent"
                                                          else self.priors)]

    def fit(self, model, samples, *, start=None, trained=None, encoder=None, seed=0) -> FitResult:
        _check(model, samples, start)
        start_time = time.perf_counter()
        rows = Rows(samples, seed)
        capped = samples if self.validation_cap is None else samples.at_most(self.validation_cap, seed)
        validation_rows = rows if capped is samples else Rows(capped, seed)
        m, grid = rows.materials, self.grid
        with frozen(model):
            scores, warm = (self.cross_validate(model, validation_rows, start, trained, seed) if len(grid) > 1
                            else (None, {}))
            if scores is None:
                best, errors = [0] * m, None
            else:
                errors = gap_errors(torch.stack([scores.per_sample[g] for g in grid]), scores.held_out)
                best = simplest_within(torch.stack([scores.loss[g] for g in grid]), errors,
                                       [self.n_params(model, g) for g in grid], self.standard_errors)
            fits = self.fit_chosen(model, rows, [grid[b] for b in best], start, trained, seed, warm,
                                   None if scores is None else scores.analytical_fits)
        table = MaterialTable(model.specs, samples.names, model.latent_dim)
        details = []
        for i, chosen in enumerate(fits):
            sub = chosen.space.to_table(chosen.x[None], MaterialTable(chosen.model.specs, [samples.names[i]],
                                                                       model.latent_dim))
            with torch.no_grad():
                for name in table.raw:
                    table.raw[name][i] = sub.raw[name][0]
                table.latent[i] = sub.latent[0]
            corrections = chosen.space.dense_corrections(chosen.x) if chosen.space.corrections else {}
            table.set_corrections(i, corrections, chosen.capacity, chosen.space.n_corrections if corrections else None)
            details.append({"prior": chosen.prior} if scores is None else
                           {"prior": chosen.prior, "cv": {label(*g): float(scores.loss[g][i]) for g in grid},
                            "cv_gap_error": {label(*g): float(errors[c, i]) for c, g in enumerate(grid)}})
        table.requires_grad_(False)
        return FitResult(table, [f.loss for f in fits], time.perf_counter() - start_time, self.describe(), details)

    def n_params(self, model: BRDFModel, candidate: tuple[str, float | None]) -> tuple[int, float]:
        """A candidate's parameters per material, then minus its prior strength: the order in which
        ``simplest_within`` prefers candidates (a stronger prior is the simpler of equal sizes)."""
        capacity, prior = candidate
        if CAPACITIES[capacity] is None:
            return analytical_model(model, capacity).n_material_params(), 0.0
        corrections = RowSpace(model, CAPACITIES[capacity](model)).n_corrections
        return model.n_material_params() + corrections, -(prior or 0.0)

    def cross_validate(self, model: BRDFModel, rows: Rows, start: MaterialTable | None, trained: MaterialTable | None,
                       seed: int) -> tuple[Validation, dict[tuple[str, float], torch.Tensor]]:
        """Every candidate of ``grid``'s validation losses per material and per held-out sample: each of
        the first ``validation_folds`` folds held out in turn, the candidate fitted to the other samples
        only (``Rows.as_problems``: a fit costs its own samples), then scored on the held-out fold;
        the held-out losses pooled over folds by their sizes. Also each candidate with corrections'
        fit on the first fold's other samples, (m, its ``RowSpace`` dim): where the fit to all the
        samples starts."""
        m, v = rows.materials, self.validation_folds
        folds = fold_masks(rows.valid, self.folds)[:v]
        material = torch.arange(m).repeat(v)
        held_out = torch.cat(list(folds))
        problems = rows.as_problems(material, ~held_out)
        scored_on = rows.as_problems(material, held_out)
        sizes = folds.sum(2).double()  # (v, m)
        side_by_side = lambda per_fold: per_fold.reshape(v, m, -1).transpose(0, 1).reshape(m, -1)  # (m, v * slots)

        def score(kernel: RowKernel, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            r = len(x) // (v * m)  # candidates stacked as blocks of v * m rows
            val = evaluate_rows(kernel, x, scored_on.layout(torch.arange(v * m).repeat(r)))
            mean = (val.train.reshape(r, v, m) * sizes).sum(1) / sizes.sum(0)
            return mean.reshape(r * m), torch.cat([side_by_side(block) for block in val.per_sample.chunk(r)])

        scores = Validation({}, {}, side_by_side(scored_on.valid))
        warm: dict[tuple[str, float], torch.Tensor] = {}

        def keep(entry: tuple[str, float | None], scored: tuple[torch.Tensor, torch.Tensor]) -> None:
            scores.loss[entry], scores.per_sample[entry] = scored

        by_state: dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}  # no alternatives: one model
        for capacity in (c for c in self.capacities if c in ANALYTICAL_CAPACITIES):
            analytical, a_space = capacity_space(model, capacity, seed)
            if analytical.state not in by_state:
                x, _ = self._analytical(model, capacity, problems, seed)
                by_state[analytical.state] = (*score(row_kernel(analytical, a_space, self.kernel), x), x[:m])
            *scored, scores.analytical_fits[capacity] = by_state[analytical.state]
            keep((capacity, None), tuple(scored))
        corrected = [(c, p) for c, p in self.grid if c not in ANALYTICAL_CAPACITIES and c != "latent"]
        if "latent" in self.capacities or corrected:
            x_latent, _ = self._latent(model, problems, material, start, trained, seed)
            if "latent" in self.capacities:
                keep(("latent", None), score(row_kernel(model, RowSpace(model), self.kernel), x_latent))
            if corrected:
                r = problems.materials
                entries = [g for g in corrected for _ in range(r)]
                kernel, fitted = self._corrections(model, problems.layout(torch.arange(r).repeat(len(corrected))),
                                                   x_latent.repeat(len(corrected), 1), entries, seed)
                x = fitted.x
                loss, per_sample = score(kernel, x)
                for g, entry in enumerate(corrected):
                    keep(entry, (loss[g * m : (g + 1) * m], per_sample[g * m : (g + 1) * m]))
                    warm[entry] = x[g * r : g * r + m, _columns(kernel.space, CAPACITIES[entry[0]](model))]
        return scores, warm

    def fit_chosen(self, model: BRDFModel, rows: Rows, chosen: list[tuple[str, float | None]],
                   start: MaterialTable | None, trained: MaterialTable | None, seed: int,
                   warm: dict[tuple[str, float], torch.Tensor] | None = None,
                   analytical_fits: dict[str, torch.Tensor] | None = None) -> list[Fitted]:
        """Each material fitted to all its samples at its ``chosen`` (capacity, prior): analytical
        capacities as ``PlainLBFGS`` fits their models alone, and also from their validation fit
        (``analytical_fits``: (m, dim) per capacity, ``cross_validate``'s) when there is one — the
        point the choice measured; an analytical fit of a few hundred samples can end in a minimum
        several times worse than that one —, latent ones by ``LatentAdam`` (the latent fit itself),
        corrected ones by the corrections' Adam run from their validation fit (``warm``: (m, dim) per
        candidate, ``cross_validate``'s) or, without one, from their latent fit."""
        warm, analytical_fits = warm or {}, analytical_fits or {}
        out: list[Fitted | None] = [None] * rows.materials
        for capacity in ANALYTICAL_CAPACITIES:
            analytical = [i for i, (c, _) in enumerate(chosen) if c == capacity]
            if analytical:
                index = torch.tensor(analytical)
                a_model, a_space = capacity_space(model, capacity, seed)
                validated = analytical_fits.get(capacity)
                x, scored = self._analytical(model, capacity, rows.as_problems(index, rows.valid[index]), seed,
                                             None if validated is None else validated[index])
                for j, i in enumerate(analytical):
                    out[i] = Fitted(capacity, None, a_model, a_space, x[j], float(scored.train[j]))
        cold = [i for i, (c, p) in enumerate(chosen) if c not in ANALYTICAL_CAPACITIES and (c, p) not in warm]
        starts: dict[int, torch.Tensor] = {i: warm[chosen[i]][i] for i, (c, p) in enumerate(chosen) if (c, p) in warm}
        if cold:
            index = torch.tensor(cold)
            x_latent, losses = self._latent(model, rows.as_problems(index, rows.valid[index]), index, start, trained,
                                            seed)
            for j, i in enumerate(cold):
                if chosen[i][0] == "latent":
                    out[i] = Fitted("latent", None, model, RowSpace(model), x_latent[j], float(losses[j]))
                else:
                    starts[i] = x_latent[j]
        if starts:
            corrected = sorted(starts)
            index = torch.tensor(corrected)
            entries = [chosen[i] for i in corrected]
            problems = rows.as_problems(index, rows.valid[index])
            layout = problems.layout(torch.arange(len(corrected)))
            kernel, fitted = self._corrections(model, layout, [starts[i] for i in corrected], entries, seed)
            for n, (i, (capacity, prior)) in enumerate(zip(corrected, entries)):
                space = RowSpace(model, CAPACITIES[capacity](model))
                out[i] = Fitted(capacity, prior, model, space, fitted.x[n, _columns(kernel.space, space.corrections)],
                                float(fitted.train[n]))
        return out

    def _analytical(self, model: BRDFModel, capacity: str, problems: Rows, seed: int,
                    also: torch.Tensor | None = None):
        """``capacity``'s analytical model's fit of every row of ``problems`` from the paper's start
        (and from ``also``, (rows, dim), when given), by ``PlainLBFGS.fit_rows``: (rows, dim) and their losses."""
        analytical, space = capacity_space(model, capacity, seed)
        x0 = space.from_table(paper_start(analytical, problems.names))
        return PlainLBFGS(iterations=self.lbfgs_iterations).fit_rows(
            row_kernel(analytical, space, self.kernel), x0, problems.layout(torch.arange(problems.materials)), also)

    @property
    def latent_protocol(self) -> LatentAdam:
        """The latent fit of the validation split and of the latent candidates: ``latent_kernel`` (None: this
        fit's kernel; rule o's jit failed, docs/BENCHMARKS.md "Stop 70"), the latent budget and
        ``latent_narrow_at`` — a quarter, as before rule m: its end point is where the corrections start, and
        the adaptive fit's end points move with it as a lottery does (docs/BENCHMARKS.md, "The latent fit's
        starts narrowed at half"); a change needs a rule of its own. ``latent_coarse_slots``: its starts'
        race's samples (``LatentAdam.coarse_slots``), None (all) unless set."""
        return LatentAdam(self.latent_epochs, starts=self.latent_starts, kernel=self.latent_kernel or self.kernel,
                          narrow_at=self.latent_narrow_at, coarse_slots=self.latent_coarse_slots)

    def _latent(self, model: BRDFModel, problems: Rows, material: torch.Tensor, start: MaterialTable | None,
                trained: MaterialTable | None, seed: int):
        """``LatentAdam``'s fit of every row of ``problems`` (rows of ``material``): (rows, dim), (rows,) losses."""
        start_rows = None if start is None else start.subset(material.tolist())
        return self.latent_protocol.fit_rows(model, problems, start_rows, trained, seed)

    def _corrections(self, model: BRDFModel, layout, starts: torch.Tensor | list[torch.Tensor],
                     entries: list[tuple[str, float]], seed: int) -> tuple[RowKernel, AdamResult]:
        """Row ``n`` of ``layout`` at capacity and prior ``entries[n]``, all in one Adam run in the
        union of their corrections (a row's other corrections stay zero), from ``starts[n]``: a
        latent fit (base dim; its corrections start at zero deltas) or a row of its own capacity's
        ``RowSpace``. Returns the union's kernel and the run: its rows (rows, its dim) and their fit losses."""
        union: list[LayerCorrection] = []
        for capacity in dict.fromkeys(c for c, _ in entries):
            union += [c for c in CAPACITIES[capacity](model) if c not in union]
        space = RowSpace(model, union)
        x0 = torch.cat([torch.zeros(layout.rows, space.base_dim), space.initial_corrections(layout.rows, seed)], 1)
        free = torch.zeros(layout.rows, space.dim, dtype=torch.bool)
        for n, (capacity, _) in enumerate(entries):
            own = _columns(space, CAPACITIES[capacity](model))
            free[n, own] = True
            x0[n, own[: len(starts[n])]] = starts[n]
        kernel = row_kernel(model, space, self.kernel)  # jit only where few factors: the union's (auto's) are many
        result = adam_rows(kernel, x0, layout, Adam(self.correction_epochs, self.correction_lr), free=free,
                           prior_strength=torch.tensor([p for _, p in entries], dtype=torch.float32))
        return kernel, result


def _columns(space: RowSpace, corrections: list[LayerCorrection] | tuple[LayerCorrection, ...]) -> torch.Tensor:
    """The columns of ``space``'s rows that a space of ``corrections`` (a subset of its own) has,
    in that space's order: the base columns, then each correction's."""
    offsets = (torch.tensor([0, *space.correction_sizes]).cumsum(0) + space.base_dim).tolist()
    own = [torch.arange(offsets[space.corrections.index(c)], offsets[space.corrections.index(c) + 1])
           for c in corrections]
    return torch.cat([torch.arange(space.base_dim), *own])
