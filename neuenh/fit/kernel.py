"""The fit kernel: every row's loss and its gradient with respect to the row's own parameters, the
model's shared module weights frozen.

A row's parameters are one vector (``RowSpace``): the analytical raw parameters (spec order), the
latent code when a module reads it, and the *corrections* its capacity frees (``Corrections``):
per-row deltas of module weights, dense or low rank, added to the shared weights. ``RowKernel``
evaluates the model for all rows of a ``layout.RowLayout`` at once and returns, per row, the mean
fit loss over its ``train`` slots (plus the prior on its corrections), the mean loss over its
``val`` slots and the gradient of the fit objective — each row's objective is its own, so a row's
gradient never depends on the rows stacked beside it.

How the frozen modules run (``RowModules``): the model's ``neural`` modules are swapped, for one
evaluation, for views that know the rows × slots grid. A layer nobody corrects is one matrix
product shared by every row; a corrected layer is one batched product with each row's own weights
(``shared + delta``), as cheap per sample. A term module's first layer splits into its
per-material part (once per row) and its per-sample part, broadcast over the row's slots instead of
gathered. No module weight takes a gradient.

The loss is the training loss (``train.log_residual``, averaged over RGB), or a Charbonnier
surrogate of it for L-BFGS (``surrogate_eps``).
"""

from __future__ import annotations

import contextlib
import copy
import math
from dataclasses import dataclass
from typing import Iterator, Sequence

import torch
from torch import nn

from ..materials import MaterialTable
from ..model import BRDFModel
from ..modules import NeuralModule
from ..rows import RowIndex, gather_rows
from ..train import log_residual
from .layout import RowLayout


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


@dataclass(frozen=True)
class LayerCorrection:
    """A per-material delta of one layer of one module: dense (``rank`` None: every weight and
    bias) or low rank (``delta W = U V``, U (out, rank), V (rank, in), plus a dense bias delta)."""

    position: str
    layer: int
    rank: int | None = None

    def shapes(self, module: NeuralModule) -> list[tuple[int, ...]]:
        """Shapes of its free parameters, in the order they sit in a row's vector."""
        out, inp = module.layers[self.layer].weight.shape
        if self.rank is None:
            return [(out, inp), (out,)]
        return [(out, self.rank), (self.rank, inp), (out,)]

    def size(self, module: NeuralModule) -> int:
        return sum(int(torch.Size(s).numel()) for s in self.shapes(module))

    def keys(self) -> tuple[str, str]:
        """The corrected weight's and bias' keys in ``model.neural.state_dict()``."""
        return f"{self.position}.layers.{self.layer}.weight", f"{self.position}.layers.{self.layer}.bias"


class RowSpace:
    """The free parameters of every row as one matrix ``x`` (rows, dim): the analytical raw values
    (spec order), the latent code if the model reads it, then each ``LayerCorrection``'s factors."""

    def __init__(self, model: BRDFModel, corrections: Sequence[LayerCorrection] = ()):
        self.model = model
        self.names = list(model.specs.names)
        self.widths = [spec.width for spec in model.specs]
        self.latent = model.uses_latent
        self.corrections = tuple(corrections)
        for c in self.corrections:
            if c.position not in model.neural:
                raise ValueError(f"no module at {c.position!r} to correct (modules: {', '.join(model.neural)})")
        self.base_dim = sum(self.widths) + (model.latent_dim if self.latent else 0)
        # ParamSpec.from_raw for every column at once (one op per step instead of one per spec)
        column = lambda f: torch.tensor([f(s) for s in model.specs for _ in range(s.width)], dtype=torch.float64)
        axis = lambda s: (math.log(s.low), math.log(s.high)) if s.scale == "log" else (s.low, s.high)
        self._axis_low = column(lambda s: axis(s)[0])
        self._axis_span = column(lambda s: axis(s)[1] - axis(s)[0])
        self._log = column(lambda s: float(s.scale == "log")).bool()
        self._low, self._high = column(lambda s: s.low), column(lambda s: s.high)
        self.correction_sizes = [c.size(model.neural[c.position]) for c in self.corrections]
        self.dim = self.base_dim + sum(self.correction_sizes)

    @property
    def n_corrections(self) -> int:
        """Free correction parameters per row (a low-rank delta counts its factors)."""
        return sum(self.correction_sizes)

    # -- tables <-> rows ----------------------------------------------------------------------
    def from_table(self, table: MaterialTable, corrections: torch.Tensor | None = None,
                   seed: int = 0) -> torch.Tensor:
        """(len(table), dim): the table's rows, then the corrections' part (``corrections`` as
        given, else the start of every correction: zero deltas; a low-rank V drawn from ``seed``)."""
        parts = [table.raw[name].detach().float() for name in self.names]
        if self.latent:
            parts.append(table.latent.detach().float())
        if self.corrections:
            parts.append(corrections if corrections is not None else self.initial_corrections(len(table), seed))
        return torch.cat(parts, dim=1)

    def initial_corrections(self, rows: int, seed: int) -> torch.Tensor:
        """Zero deltas: dense parts and low-rank U are 0; a low-rank V is random (Xavier-scaled,
        the same for every row) so U's gradient is not zero."""
        generator = torch.Generator().manual_seed(seed)
        parts = []
        for c in self.corrections:
            for k, shape in enumerate(c.shapes(self.model.neural[c.position])):
                if c.rank is not None and k == 1:
                    v = torch.randn(*shape, generator=generator) * (1.0 / shape[1]) ** 0.5
                    parts.append(v.reshape(1, -1).expand(rows, -1))
                else:
                    parts.append(torch.zeros(rows, int(torch.Size(shape).numel())))
        return torch.cat(parts, dim=1) if parts else torch.zeros(rows, 0)

    def to_table(self, x: torch.Tensor, table: MaterialTable) -> MaterialTable:
        """Write rows ``x`` (len(table), dim) into ``table``'s analytical and latent parameters."""
        parts = torch.split(x[:, : self.base_dim].detach().float(), self.widths + ([table.latent_dim] if self.latent else []),
                            dim=1)
        with torch.no_grad():
            for name, part in zip(self.names, parts):
                table.raw[name].copy_(part)
            if self.latent:
                table.latent.copy_(parts[-1])
        return table

    # -- rows -> what the model reads -----------------------------------------------------------
    def values(self, x: torch.Tensor) -> tuple[dict[str, torch.Tensor], torch.Tensor | None]:
        """Physical values (rows, width) per parameter and the latent code (rows, latent_dim), or
        None when no module reads it."""
        analytical = sum(self.widths)
        low, span, lo, hi = (t.to(x.dtype) for t in (self._axis_low, self._axis_span, self._low, self._high))
        axis = low + span * torch.sigmoid(x[:, :analytical])
        # exp only where the axis is logarithmic (a linear column's value could overflow it)
        value = torch.where(self._log, torch.exp(torch.where(self._log, axis, 0.0)), axis)
        value = torch.minimum(torch.maximum(value, lo), hi)  # round-off stays in range
        values = dict(zip(self.names, torch.split(value, self.widths, dim=1)))
        return values, x[:, analytical : self.base_dim] if self.latent else None

    def factors(self, x: torch.Tensor) -> dict[LayerCorrection, list[torch.Tensor]]:
        """Each correction's free parameters per row, (rows, *shape) in ``LayerCorrection.shapes``' order."""
        out = {}
        offset = self.base_dim
        rows = x.shape[0]
        for c, size in zip(self.corrections, self.correction_sizes):
            shapes = c.shapes(self.model.neural[c.position])
            flat = torch.split(x[:, offset : offset + size], [int(torch.Size(s).numel()) for s in shapes], dim=1)
            out[c] = [f.reshape(rows, *s) for f, s in zip(flat, shapes)]
            offset += size
        return out

    def deltas(self, x: torch.Tensor) -> dict[LayerCorrection, tuple[torch.Tensor, torch.Tensor]]:
        """Each correction's dense (rows, out, in) weight delta and (rows, out) bias delta."""
        return dense_deltas(self.factors(x))

    def penalty(self, x: torch.Tensor, strength: torch.Tensor, grad: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(rows,) ``strength * prior(x)`` and, with ``grad``, its gradient (rows, dim) with respect to ``x``."""
        with torch.enable_grad() if grad else torch.no_grad():
            leaf = x.detach().clone().requires_grad_(grad)
            penalty = strength * self.prior(leaf)
            gradient = torch.autograd.grad(penalty.sum(), leaf)[0] if grad else None
        return penalty.detach(), gradient

    def dense_corrections(self, x_row: torch.Tensor) -> dict[str, torch.Tensor]:
        """One row's corrections as dense deltas keyed like ``model.neural.state_dict()``."""
        out = {}
        for c, (weight, bias) in self.deltas(x_row.reshape(1, -1)).items():
            for key, delta in zip(c.keys(), (weight[0], bias[0])):
                out[key] = out[key] + delta.detach() if key in out else delta.detach().clone()
        return {k: v for k, v in out.items() if bool(v.abs().max() > 0)}

    def prior(self, x: torch.Tensor) -> torch.Tensor:
        """(rows,) the corrections' squared size relative to the weights they correct:
        sum over corrected layers of (|dW|^2 + |db|^2) / (|W|^2 + |b|^2)."""
        total = torch.zeros(x.shape[0], dtype=x.dtype)
        for c, (weight, bias) in self.deltas(x).items():
            layer = self.model.neural[c.position].layers[c.layer]
            scale = float(layer.weight.detach().square().sum() + layer.bias.detach().square().sum())
            total = total + (weight.square().sum((1, 2)) + bias.square().sum(1)) / scale
        return total


def dense_deltas(factors: dict[LayerCorrection, list[torch.Tensor]]) -> dict[LayerCorrection, tuple[torch.Tensor, torch.Tensor]]:
    """``RowSpace.deltas`` from ``RowSpace.factors``: a low-rank delta's ``U V``, a dense one as it is."""
    return {c: (f[0] if c.rank is None else torch.bmm(f[0], f[1]), f[-1]) for c, f in factors.items()}


class _RowModule(nn.Module):
    """A frozen ``NeuralModule`` evaluated on a rows × slots grid, each corrected layer with every
    row's own weights (``shared + delta``). Same interface as the module (``forward``,
    ``forward_indexed``) so the model's own forward runs unchanged."""

    def __init__(self, module: NeuralModule, rows: int, weights: dict[int, tuple[torch.Tensor, torch.Tensor]]):
        super().__init__()
        self.shared = module
        self.rows = rows
        self.weights = weights  # layer -> (rows, out, in) weights and (rows, out) biases of that layer
        self.negative_slope = module.negative_slope

    def _layer(self, i: int, x: torch.Tensor) -> torch.Tensor:
        """Layer ``i`` on x (rows * s, in) -> (rows * s, out)."""
        if i not in self.weights:
            layer = self.shared.layers[i]
            return torch.addmm(layer.bias, x, layer.weight.t())
        weight, bias = self.weights[i]
        grid = x.reshape(self.rows, -1, x.shape[-1])
        return torch.baddbmm(bias.unsqueeze(1), grid, weight.transpose(1, 2)).reshape(-1, weight.shape[1])

    def _rest(self, x: torch.Tensor) -> torch.Tensor:
        for i in range(1, len(self.shared.layers)):
            # not in place: x is often a reshaped view of a batched product, and autograd takes an in-place
            # op on a view back through a zeroed copy of the whole product (a correction step 8 % slower;
            # docs/BENCHMARKS.md, "The C allocator's page faults")
            x = self._layer(i, nn.functional.leaky_relu(x, self.negative_slope))
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self._rest(self._layer(0, x))

    def forward_indexed(self, per_material: torch.Tensor, per_sample: torch.Tensor | None,
                        material: RowIndex) -> torch.Tensor:
        """``per_material`` (rows, P): one row per grid row; ``per_sample`` (rows * s, Q); the
        per-row part of the first layer is broadcast over the row's slots."""
        if per_sample is None:
            return gather_rows(self.forward(per_material), material)
        k = per_material.shape[1]
        if 0 in self.weights:
            weight, bias = self.weights[0]
            row_part = torch.baddbmm(bias.unsqueeze(1), per_material.unsqueeze(1), weight[:, :, :k].transpose(1, 2))
            grid = per_sample.reshape(self.rows, -1, per_sample.shape[-1])
            x = torch.baddbmm(row_part, grid, weight[:, :, k:].transpose(1, 2))
        else:
            first = self.shared.layers[0]
            row_part = torch.addmm(first.bias, per_material, first.weight[:, :k].t()).unsqueeze(1)
            x = (per_sample @ first.weight[:, k:].t()).reshape(self.rows, -1, first.out_features) + row_part
        return self._rest(x.reshape(-1, x.shape[-1]))


def row_view(model: BRDFModel, rows: int, deltas: dict[LayerCorrection, tuple[torch.Tensor, torch.Tensor]]
             ) -> BRDFModel:
    """``model`` with its modules replaced by ``_RowModule`` views for a grid of ``rows`` rows (the
    model itself is untouched; the view shares everything else)."""
    view = copy.copy(model)
    view._modules = dict(model._modules)
    per_module: dict[str, dict[int, tuple[torch.Tensor, torch.Tensor]]] = {}
    for c, (weight, bias) in deltas.items():  # two corrections of one layer add up
        layer = model.neural[c.position].layers[c.layer]
        w, b = per_module.setdefault(c.position, {}).get(c.layer, (layer.weight, layer.bias))
        per_module[c.position][c.layer] = (w + weight, b + bias)
    view.neural = nn.ModuleDict({name: _RowModule(module, rows, per_module.get(name, {}))
                                 for name, module in model.neural.items()})
    return view


@dataclass
class RowLosses:
    train: torch.Tensor  # (rows,) float64 mean fit loss over the row's train slots (no prior)
    val: torch.Tensor  # (rows,) float64 mean loss over its val slots (NaN without any)
    objective: torch.Tensor  # (rows,) float64 what is minimised: train (or its surrogate) + prior
    grad: torch.Tensor | None  # (rows, dim) gradient of objective
    per_sample: torch.Tensor | None = None  # (rows, slots) float64 each slot's loss (padding's is meaningless)


# Slots a row a kernel evaluates at once (``RowKernel``): above it, in chunks of this many.
CHUNK_SLOTS = 100_000


class RowKernel:
    """Losses and gradients of every row of a layout (module doc). ``prior_strength`` (rows,)
    weighs each row's ``RowSpace.prior``; rows without corrections ignore it.

    A layout of more than ``chunk_slots`` slots a row (a material of more samples, fitted whole) is
    evaluated ``chunk_slots`` slots at a time, each chunk's share of the objective differentiated on
    its own and the gradients summed: the same objective and gradient up to rounding, in the memory
    of one chunk (the activations take kilobytes a sample and row: docs/BENCHMARKS.md, "A fit's memory,
    bounded by blocks of materials"). Layouts up to it run in one pass, as always."""

    def __init__(self, model: BRDFModel, space: RowSpace):
        self.model, self.space = model, space
        # the rows' dtype follows the model's weights (float32; a float64 copy gives a reference)
        self.dtype = next(iter(model.parameters()), torch.zeros(0)).dtype

    def _fitted(self, x: torch.Tensor, layout: RowLayout, surrogate_eps: float | None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """Each slot's loss (rows, slots) and what the fit minimises of it (the loss or its surrogate)."""
        rows = layout.rows
        values, latent = self.space.values(x)
        view = row_view(self.model, rows, self.space.deltas(x))
        pred = view.forward_indexed(layout.wi, layout.wo, values, latent, layout.grid)
        residual = log_residual(pred, layout.f_r, layout.wi)
        per_sample = residual.abs().mean(dim=1).reshape(rows, -1)
        if surrogate_eps is None:
            return per_sample, per_sample
        # Charbonnier (Charbonnier et al. 1994): smooth, within eps of |r| everywhere
        return per_sample, ((residual * residual + surrogate_eps ** 2).sqrt() - surrogate_eps).mean(dim=1).reshape(rows, -1)

    def __call__(self, x: torch.Tensor, layout: RowLayout, *, grad: bool = True,
                 prior_strength: torch.Tensor | None = None, surrogate_eps: float | None = None,
                 chunk_slots: int = CHUNK_SLOTS) -> RowLosses:
        if chunk_slots < 1:
            raise ValueError(f"chunk_slots must be at least 1, got {chunk_slots}")
        x = x.detach().to(self.dtype)
        weight = layout.train.sum(1).clamp_min(1e-12)
        prior = prior_strength is not None and self.space.corrections
        if layout.slots <= chunk_slots:
            with torch.enable_grad() if grad else torch.no_grad():
                if grad:
                    x.requires_grad_(True)
                per_sample, fitted = self._fitted(x, layout, surrogate_eps)
                objective = (fitted * layout.train).sum(1) / weight
                if prior:
                    objective = objective + prior_strength * self.space.prior(x)
                g = torch.autograd.grad(objective.sum(), x)[0] if grad else None
            per_sample, objective = per_sample.detach(), objective.detach()
        else:
            objective, g, parts = torch.zeros(layout.rows, dtype=self.dtype), None, []
            for lo in range(0, layout.slots, chunk_slots):
                share, g_share, per_part = self._chunk(x, layout.chunk(lo, min(lo + chunk_slots, layout.slots)),
                                                       weight, grad, surrogate_eps)
                objective += share
                parts.append(per_part)
                g = g_share if g is None else g + g_share
            per_sample = torch.cat(parts, 1)
            if prior:
                penalty, g_penalty = self.space.penalty(x, prior_strength, grad)
                objective = objective + penalty
                g = g + g_penalty if grad else g
        with torch.no_grad():
            per = per_sample.double()
            train = (per * layout.train).sum(1) / layout.train.sum(1).double().clamp_min(1e-12)
            val_weight = layout.val.sum(1).double()
            val = torch.where(val_weight > 0, (per * layout.val).sum(1) / val_weight.clamp_min(1e-12), torch.nan)
        return RowLosses(train, val, objective.double(), g, per)

    def _chunk(self, x: torch.Tensor, part: RowLayout, weight: torch.Tensor, grad: bool, surrogate_eps: float | None
               ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """One chunk of slots: its share of every row's objective (its train slots' sum over the row's
        whole ``weight``), that share's gradient, and its slots' losses."""
        with torch.enable_grad() if grad else torch.no_grad():
            leaf = x.clone().requires_grad_(grad)
            per_sample, fitted = self._fitted(leaf, part, surrogate_eps)
            share = (fitted * part.train).sum(1) / weight
            g = torch.autograd.grad(share.sum(), leaf)[0] if grad else None
        return share.detach(), g, per_sample.detach()
