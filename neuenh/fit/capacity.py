"""Adaptive capacity: per-material corrections of module weights, and a fit that chooses how much
freedom each material's data supports.

Beyond its analytical parameters and latent code, a material may carry *corrections*: deltas of the
shared module weights that are its own (``kernel.LayerCorrection``), pulled towards the shared
weights by an L2 prior (``kernel.RowSpace.prior``, relative to each corrected layer's size). A
*capacity* names which corrections are free:

==============  =================================================================================
``analytical``  the analytical model of the same graph (modules back to their original terms)
``latent``      the latent code and analytical parameters (the paper's fit)
``last-layer``  + the last layer of every module, dense
``low-rank``    + the last layer dense and a rank-``LOW_RANK`` delta of every other layer
``full``        + every layer of every module, dense
==============  =================================================================================

``Adaptive`` fits each material at every capacity (and every prior strength of a grid) and keeps
the one with the lowest cross-validation loss on its own fit data (k folds: each fold's samples are
scored by a fit to the other folds); the chosen capacity's fit to all the samples is the result.
Every capacity, strength and fold is a row of one batch (``layout``), so the search is one fit of
many rows, not many fits: the analytical candidate is one stacked L-BFGS run, the latent one one
stacked multi-start Adam run (``LatentAdam``), the corrections one Adam run from the latent fits of
the same folds.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, ClassVar

import torch

from ..materials import MaterialTable
from ..model import BRDFModel
from .kernel import LayerCorrection, RowKernel, RowLosses, RowSpace, frozen
from .layout import fold_masks
from .optim import Adam, adam_rows, evaluate_rows
from .protocols import FitProtocol, LatentAdam, PlainLBFGS, Rows, _check, paper_start
from .result import FitResult

LOW_RANK = 2

CAPACITIES: dict[str, Callable[[BRDFModel], list[LayerCorrection]] | None] = {
    "analytical": None,
    "latent": lambda model: [],
    "last-layer": lambda model: [LayerCorrection(p, len(m.layers) - 1) for p, m in model.neural.items()],
    "low-rank": lambda model: [LayerCorrection(p, i, None if i == len(m.layers) - 1 else LOW_RANK)
                               for p, m in model.neural.items() for i in range(len(m.layers))],
    "full": lambda model: [LayerCorrection(p, i) for p, m in model.neural.items() for i in range(len(m.layers))],
}


def capacity_space(model: BRDFModel, capacity: str, seed: int = 0) -> tuple[BRDFModel, RowSpace]:
    """The model a capacity evaluates (the analytical state's for ``analytical``) and its rows' space."""
    if capacity not in CAPACITIES:
        raise ValueError(f"unknown capacity {capacity!r} (capacities: {', '.join(CAPACITIES)})")
    if CAPACITIES[capacity] is None:
        analytical = model.enhance(model.analytical_state(), seed)
        return analytical, RowSpace(analytical)
    return model, RowSpace(model, CAPACITIES[capacity](model))


@dataclass
class Candidate:
    """One (capacity, prior strength) of an adaptive fit: every material's fit to all its samples
    (``x``, rows of ``space``), its cross-validation loss and its fit loss."""

    capacity: str
    prior: float | None
    model: BRDFModel
    space: RowSpace
    x: torch.Tensor  # (m, space.dim)
    cv: torch.Tensor  # (m,) float64; NaN when the candidate was not cross-validated (the only one)
    fit: torch.Tensor  # (m,) float64

    @property
    def label(self) -> str:
        return self.capacity + ("" if self.prior is None else f"@{self.prior:g}")


@dataclass(frozen=True)
class Adaptive(FitProtocol):
    """Capacity and prior strength per material by ``folds``-fold cross-validation (module doc).

    ``capacities``: the candidates, from ``CAPACITIES``; ``priors``: the prior strengths tried for
    each capacity with corrections. Budgets: the analytical candidate by ``PlainLBFGS``
    (``lbfgs_iterations``), the latent one by ``LatentAdam`` (``latent_epochs``, from
    ``latent_starts``), corrections by ``correction_epochs`` Adam epochs at lr ``correction_lr``
    from the latent fit of the same fold. A single candidate is fitted without folds."""

    name: ClassVar[str] = "adaptive"
    capacities: tuple[str, ...] = ("analytical", "latent", "last-layer", "low-rank")
    priors: tuple[float, ...] = (1e-3, 1e-2)
    folds: int = 3
    latent_epochs: int = 300
    latent_starts: str = "analytical"
    lbfgs_iterations: int = 300
    correction_epochs: int = 150
    correction_lr: float = 0.01

    def __post_init__(self) -> None:
        unknown = [c for c in self.capacities if c not in CAPACITIES]
        if unknown or not self.capacities:
            raise ValueError(f"unknown capacities {unknown} (known: {', '.join(CAPACITIES)})")
        if self.folds < 2 or not self.priors or any(p < 0 for p in self.priors) or self.correction_epochs < 1:
            raise ValueError(f"invalid adaptive protocol {self}")

    @property
    def budget_epochs(self) -> int:  # every fold's fit and the fit to all the samples
        return (self.folds + 1) * self.latent_epochs

    @property
    def grid(self) -> list[tuple[str, float | None]]:
        return [(c, p) for c in self.capacities for p in ((None,) if CAPACITIES[c] is None or c == "latent"
                                                          else self.priors)]

    def fit(self, model, samples, *, start=None, trained=None, seed=0) -> FitResult:
        start_time = time.perf_counter()
        candidates = self.candidates(model, samples, start=start, trained=trained, seed=seed)
        m = len(samples.names)
        single = len(candidates) == 1
        scores = torch.stack([c.cv for c in candidates])  # (candidates, m)
        choice = torch.zeros(m, dtype=torch.long) if single else scores.argmin(0)
        table = MaterialTable(model.specs, samples.names, model.latent_dim)
        losses, details = [], []
        for i in range(m):
            chosen = candidates[int(choice[i])]
            x = chosen.x[i : i + 1]
            chosen.space.to_table(x, sub := MaterialTable(chosen.model.specs, [samples.names[i]], model.latent_dim))
            with torch.no_grad():
                for name in table.raw:
                    table.raw[name][i] = sub.raw[name][0]
                table.latent[i] = sub.latent[0]
            corrections = chosen.space.dense_corrections(x[0]) if chosen.space.corrections else {}
            table.set_corrections(i, corrections, chosen.capacity, chosen.space.n_corrections if corrections else None)
            losses.append(float(chosen.fit[i]))
            details.append({"prior": chosen.prior, "cv": {c.label: float(c.cv[i]) for c in candidates}})
        table.requires_grad_(False)
        return FitResult(table, losses, time.perf_counter() - start_time, self.describe(), details)

    def candidates(self, model: BRDFModel, samples, *, start: MaterialTable | None = None,
                   trained: MaterialTable | None = None, seed: int = 0) -> list[Candidate]:
        """Every candidate of the grid fitted to every material, with its cross-validation loss."""
        _check(model, samples, start)
        rows = Rows(samples, seed)
        m = rows.materials
        k = 0 if len(self.grid) == 1 else self.folds
        folds = fold_masks(rows.valid, k) if k else torch.zeros(0, m, rows.valid.shape[1], dtype=torch.bool)
        # the rows of every stage: fold 0..k-1 of every material, then every material on all its samples
        material = torch.arange(m).repeat(k + 1)
        train = torch.cat([rows.valid & ~folds[f] for f in range(k)] + [rows.valid])
        val = torch.cat([folds[f] for f in range(k)] + [torch.zeros_like(rows.valid)])
        layout = rows.layout(material, train, val)
        out: list[Candidate] = []

        def keep(capacity, prior, cand_model, space, x, scored_val, scored_train):
            cv = _cv(scored_val, k, m, folds) if k else torch.full((m,), float("nan"), dtype=torch.float64)
            out.append(Candidate(capacity, prior, cand_model, space, x[k * m:], cv, scored_train[k * m:]))

        with frozen(model):
            if "analytical" in self.capacities:
                analytical, a_space = capacity_space(model, "analytical", seed)
                x_a, scored = self._analytical(analytical, a_space, rows, layout, k)
                keep("analytical", None, analytical, a_space, x_a, scored.val, scored.train)
            if any(c != "analytical" for c in self.capacities):
                latent = LatentAdam(self.latent_epochs, starts=self.latent_starts)
                start_rows = None if start is None else _repeat_table(start, k + 1)
                x_latent, _ = latent.fit_rows(model, rows.as_problems(material, train), start_rows, trained, seed)
                space = RowSpace(model)
                if "latent" in self.capacities:
                    scored = evaluate_rows(RowKernel(model, space), x_latent, layout)
                    keep("latent", None, model, space, x_latent, scored.val, scored.train)
                grid = [(c, p) for c, p in self.grid if c not in ("analytical", "latent")]
                if grid:
                    for (capacity, prior), (c_space, x, scored_val, scored_train) in zip(
                            grid, self._corrections(model, layout, x_latent, grid, seed)):
                        keep(capacity, prior, model, c_space, x, scored_val, scored_train)
        return out

    def _analytical(self, analytical: BRDFModel, space: RowSpace, rows: Rows, layout, k: int):
        """The analytical model's fit of every row (``PlainLBFGS.fit_rows``). The rows on all of a
        material's samples run on their own, exactly as ``PlainLBFGS`` fits the material alone:
        stacked beside the folds, float32 rounding could send a rough landscape's L-BFGS elsewhere,
        and the adaptive fit is to end where the analytical-only fit ends when it picks it."""
        kernel = RowKernel(analytical, space)
        plain = PlainLBFGS(iterations=self.lbfgs_iterations)
        m = rows.materials
        x0 = space.from_table(paper_start(analytical, rows.names))
        parts = [plain.fit_rows(kernel, x0.repeat(k, 1), layout.select(torch.arange(k * m)))] if k else []
        parts.append(plain.fit_rows(kernel, x0, layout.select(torch.arange(k * m, (k + 1) * m))))
        x = torch.cat([p[0] for p in parts])
        scored = RowLosses(*(torch.cat([getattr(p[1], f) for p in parts]) for f in ("train", "val", "objective")), None)
        return x, scored

    def _corrections(self, model, layout, x_latent, grid, seed):
        """Every (capacity, prior) of ``grid`` as rows of one Adam run from the latent fits; per
        entry its own space, its rows and their validation and fit losses."""
        union: list[LayerCorrection] = []
        for capacity, _ in grid:
            union += [c for c in CAPACITIES[capacity](model) if c not in union]
        space = RowSpace(model, union)
        kernel = RowKernel(model, space)
        r = layout.rows
        x0 = torch.cat([x_latent, space.initial_corrections(r, seed)], 1).repeat(len(grid), 1)
        free = torch.zeros(len(grid) * r, space.dim, dtype=torch.bool)
        free[:, : space.base_dim] = True
        strength = torch.zeros(len(grid) * r)
        offsets = (torch.tensor([0, *space.correction_sizes]).cumsum(0) + space.base_dim).tolist()
        columns = []
        for g, (capacity, prior) in enumerate(grid):
            own = CAPACITIES[capacity](model)
            cols = [torch.arange(space.base_dim)]
            for c in own:
                j = union.index(c)
                free[g * r : (g + 1) * r, offsets[j] : offsets[j + 1]] = True
                cols.append(torch.arange(offsets[j], offsets[j + 1]))
            columns.append(torch.cat(cols))
            strength[g * r : (g + 1) * r] = prior
        result = adam_rows(kernel, x0, layout.select(torch.arange(r).repeat(len(grid))),
                           Adam(self.correction_epochs, self.correction_lr), free=free, prior_strength=strength)
        out = []
        for g, (capacity, _) in enumerate(grid):
            part = slice(g * r, (g + 1) * r)
            out.append((RowSpace(model, CAPACITIES[capacity](model)), result.x[part][:, columns[g]],
                        result.val[part], result.train[part]))
        return out


def _cv(val: torch.Tensor, k: int, m: int, folds: torch.Tensor) -> torch.Tensor:
    """(m,) each material's cross-validation loss: its folds' validation losses weighted by size."""
    sizes = folds.sum(2).double()  # (k, m)
    per_fold = val[: k * m].reshape(k, m)
    return (per_fold * sizes).sum(0) / sizes.sum(0)


def _repeat_table(table: MaterialTable, times: int) -> MaterialTable:
    return MaterialTable(table.specs, tuple(table.names) * times, table.latent_dim,
                         {n: v.detach().repeat(times, 1) for n, v in table.raw.items()},
                         table.latent.detach().repeat(times, 1))
