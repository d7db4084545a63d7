"""Row-wise optimisers over a ``kernel.RowKernel``: every row an independent problem, one batch.

* ``adam_rows`` — Adam (Kingma & Ba 2015, Alg. 1; PyTorch's constants) with a cosine learning
  rate from ``lr`` to ``lr * final_ratio``, full batch or minibatches along the slots, optionally
  narrowing competing starts to each group's best (successive halving; Jamieson & Talwalkar 2016).
* ``lbfgs_rows`` — row-wise L-BFGS (``neuenh.lbfgs``) on a Charbonnier surrogate of the loss, each
  phase with a smaller eps (``SURROGATE_EPS``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch

from ..lbfgs import minimize_rows
from ..optimizers import ADAM_BETAS, ADAM_EPS
from .kernel import RowKernel, RowLosses
from .layout import RowLayout

# The fast fit's L-BFGS minimises a Charbonnier surrogate of the log-L1, sqrt(r^2 + eps^2) - eps per
# channel: smooth, so curvature pairs are meaningful, and within eps of |r| everywhere. Each phase
# starts from the last one's result with a smaller eps (the second is below the residuals that
# matter). The losses a fit reports are always the true log-L1.
SURROGATE_EPS = (1e-2, 1e-3)


@dataclass(frozen=True)
class Adam:
    """A row-wise Adam run: ``epochs`` passes over every row's slots, in minibatches of
    ``batch_slots`` slots per row (None: full batch, one step per epoch), learning rate ``lr``
    decaying by a cosine to ``lr * final_ratio``."""

    epochs: int
    lr: float
    final_ratio: float = 1e-3
    batch_slots: int | None = None

    def __post_init__(self) -> None:
        if self.epochs < 0 or self.lr <= 0 or not 0 < self.final_ratio <= 1 or (
                self.batch_slots is not None and self.batch_slots < 1):
            raise ValueError(f"invalid Adam run {self}")


@dataclass
class AdamResult:
    x: torch.Tensor  # (rows, dim) the end points
    rows: torch.Tensor  # (rows,) which input rows these are (narrowing drops some)
    train: torch.Tensor  # (rows,) mean fit loss at ``x`` (exact, full layout)


def adam_rows(kernel: RowKernel, x: torch.Tensor, layout: RowLayout, run: Adam, *,
              free: torch.Tensor | None = None, prior_strength: torch.Tensor | None = None,
              groups: torch.Tensor | None = None, narrow_at: float = 0.25, seed: int = 0,
              narrowed_layout: RowLayout | None = None, lr_scale: torch.Tensor | None = None) -> AdamResult:
    """Adam over every row of ``x`` (rows, dim) on ``layout`` (module doc); ``lr_scale`` (rows,): each
    row's factor on the run's learning rate (default 1: several runs of one schedule as one batch).

    ``free`` (dim,) or (rows, dim) bool: the columns that move (default all). ``groups`` (rows,): rows with the
    same id are starts of one problem; after ``narrow_at`` of the epochs each group keeps its row of
    lowest fit loss (with its moments) and the others are dropped. ``narrowed_layout``: the same rows
    on more of their samples (e.g. ``layout`` is its first slots, a random subset): each group's
    best is chosen on it, and the kept rows run on it from then on (needs ``groups``)."""
    x = x.detach().float().clone()
    rows = torch.arange(len(x))
    moment1, moment2 = torch.zeros_like(x), torch.zeros_like(x)
    narrow = int(narrow_at * run.epochs) if groups is not None else -1
    if narrowed_layout is not None and (groups is None or narrowed_layout.rows != layout.rows):
        raise ValueError("a narrowed layout needs groups of starts and the layout's rows")
    generator = torch.Generator().manual_seed(seed)
    step = 0
    for epoch in range(run.epochs):
        if epoch == narrow:
            layout = layout if narrowed_layout is None else narrowed_layout
            keep = _best_of_groups(kernel, x, layout, groups, prior_strength)
            x, moment1, moment2, rows = x[keep], moment1[keep], moment2[keep], rows[keep]
            layout = layout.select(keep)
            prior_strength = None if prior_strength is None else prior_strength[keep]
            free = free[keep] if free is not None and free.ndim == 2 else free
            lr_scale = None if lr_scale is None else lr_scale[keep]
            groups = None
        rate = run.lr * (run.final_ratio + (1 - run.final_ratio) * 0.5 * (1 + math.cos(math.pi * epoch / run.epochs)))
        for batch in layout.minibatches(run.batch_slots or layout.slots, generator):
            losses = kernel(x, batch, prior_strength=prior_strength)
            grad = losses.grad if free is None else losses.grad * free
            step += 1
            moment1.mul_(ADAM_BETAS[0]).add_(grad, alpha=1 - ADAM_BETAS[0])
            moment2.mul_(ADAM_BETAS[1]).addcmul_(grad, grad, value=1 - ADAM_BETAS[1])
            denom = (moment2 / (1 - ADAM_BETAS[1] ** step)).sqrt_().add_(ADAM_EPS)
            size = rate / (1 - ADAM_BETAS[0] ** step)
            x = x - (size if lr_scale is None else size * lr_scale[:, None]) * moment1 / denom
    final = kernel(x, layout, grad=False, prior_strength=prior_strength)
    return AdamResult(x, rows, final.train)


def _best_of_groups(kernel: RowKernel, x: torch.Tensor, layout: RowLayout, groups: torch.Tensor,
                    prior_strength: torch.Tensor | None) -> torch.Tensor:
    """The index of each group's row with the lowest fit objective, groups in order of first appearance."""
    objective = kernel(x, layout, grad=False, prior_strength=prior_strength).objective
    keep = []
    for g in dict.fromkeys(groups.tolist()):
        members = torch.nonzero(groups == g).squeeze(1)
        keep.append(int(members[objective[members].argmin()]))
    return torch.tensor(keep, dtype=torch.long)


def lbfgs_rows(kernel: RowKernel, x: torch.Tensor, layout: RowLayout, max_iter: int,
               phases: Sequence[float] = SURROGATE_EPS) -> tuple[torch.Tensor, int]:
    """Row-wise L-BFGS of every row of ``x`` on ``layout``, one phase per surrogate eps of ``phases``
    (default all of ``SURROGATE_EPS``), each at most ``max_iter`` iterations, in float64. Returns the
    end points (float64, so a later phase continues from them unrounded) and the iterations the
    slowest row ran."""
    x = x.detach().double()
    iterations = 0
    for eps in phases:
        def objective(point: torch.Tensor, wanted: torch.Tensor, eps: float = eps):
            if bool(wanted.all()):
                losses = kernel(point, layout, surrogate_eps=eps)
                return losses.objective, losses.grad.double()
            index = torch.nonzero(wanted).squeeze(1)  # only the rows still backtracking
            losses = kernel(point[index], layout.select(index), surrogate_eps=eps)
            objective = torch.zeros(len(point), dtype=torch.float64)
            grad = torch.zeros_like(point)
            objective[index], grad[index] = losses.objective, losses.grad.double()
            return objective, grad

        result = minimize_rows(objective, x, max_iter=max_iter)
        x = result.x
        iterations += int(result.iterations.max())
    return x, iterations


def evaluate_rows(kernel: RowKernel, x: torch.Tensor, layout: RowLayout, batch_slots: int = 50_000) -> RowLosses:
    """Exact losses of every row (no gradient), ``batch_slots`` slots at a time so memory stays
    bounded (the kernel's chunks)."""
    return kernel(x, layout, grad=False, chunk_slots=batch_slots)
