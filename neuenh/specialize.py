"""One material's BRDF, specialized: its parameters folded in, ``(wi, wo) -> f_r`` in few ops.

``BRDFModel.evaluate`` serves any batch of materials: every call validates and broadcasts the
parameters, builds the shading frame per sample, and feeds every neural module the 12 analytical
+ latent parameters of each sample. For one material all of that is constant. ``specialize``
computes it once:

* the shading frame (``normal``, ``t_theta``) becomes one 3x3 rotation;
* each module that reads the per-material inputs gets them folded into its first-layer bias
  (``b1 + W1[:, :P] @ [unit params, latent]``, computed in float64), so its first layer reads only
  the directions (6 inputs) — or nothing, and then its output is a constant;
* terms that read no direction (``M``, ``S``, ...) and operators over constants are computed once;
* the remaining expression runs the backend-neutral term formulas (``neuenh.ops``) with the
  parameters as Python constants, so Python folds their arithmetic too.

``SpecializedBRDF`` is what the renderer, the report, the service's fit predictions and the
exporters (``neuenh.export``) use; ``folded`` exposes the pieces an exporter needs. Its result
equals ``evaluate`` (tested on the stability grid) and reports its cost: FLOPs per evaluation and
measured evaluations per second.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import torch

from .graph import Expr, Operator, Term, V, apply, fold
from .materials import MaterialParams
from .ops import TORCH, BatchVec3
from .shading import Shading, frame_of, shade

# Rows per pass: the intermediates of a chunk stay in cache (measured in bench/bench_speed.py:
# unchunked batches of 1e5 pay for page faults and memory traffic on every (n, 32) intermediate).
CHUNK = 16_384


@dataclass(frozen=True)
class FoldedModule:
    """A neural module with one material's constant inputs folded in.

    ``layers[0]`` reads only the per-sample inputs: ``[wi_s, wo_s]`` (6, shading frame) for a term
    that reads directions, the operands ``[left, right]`` for an operator; its bias includes the
    folded per-material inputs. Weights are ``(out, in)`` float32 tensors, as in ``nn.Linear``.
    """

    position: str
    layers: tuple[tuple[torch.Tensor, torch.Tensor], ...]
    negative_slope: float

    @property
    def flops(self) -> int:
        """Multiply-adds as two FLOPs, plus the bias add and one op per activation."""
        total = 0
        for i, (weight, _) in enumerate(self.layers):
            out, inp = weight.shape
            total += 2 * out * inp + out + (out if i < len(self.layers) - 1 else 0)
        return total

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        last = len(self.layers) - 1
        for i, (weight, bias) in enumerate(self.layers):
            x = torch.addmm(bias, x, weight.t())
            if i < last:
                torch.nn.functional.leaky_relu_(x, self.negative_slope)
        return x

    def to(self, dtype: torch.dtype) -> "FoldedModule":
        layers = tuple((w.to(dtype).contiguous(), b.to(dtype)) for w, b in self.layers)
        return FoldedModule(self.position, layers, self.negative_slope)

    def as_floats(self) -> tuple[list, list, float]:
        """The layers as Python floats (weights row by row, biases) and the slope: what an unrolled
        evaluation (``unrolled_mlp``: the Mitsuba plugin, the fit's Dr.Jit kernel) folds into its code."""
        return ([[[float(w) for w in row] for row in weight.tolist()] for weight, _ in self.layers],
                [[float(b) for b in bias.tolist()] for _, bias in self.layers], self.negative_slope)


def unrolled_mlp(xp, module: tuple[list, list, float], inputs: list, first_bias: list | None = None,
                 after_layer: Callable[[int, list, list], list] | None = None) -> list:
    """The MLP ``FoldedModule.as_floats`` holds, on a backend's per-sample values (``neuenh.ops``; Dr.Jit's):
    a product per non-zero weight, LeakyReLU (``max(x, slope x)``, slope below 1) between layers; its
    outputs as a list. ``first_bias``: per-sample values in place of the first layer's bias (the fit's
    rows, whose inputs are folded in per row); ``after_layer(layer, its inputs, its outputs)``: the
    outputs to go on with, before the activation (the fit's per-row corrections of a layer)."""
    weights, biases, slope = module
    x = inputs
    for layer, (weight, bias) in enumerate(zip(weights, biases)):
        out = []
        for row, b in zip(weight, first_bias if layer == 0 and first_bias is not None else bias):
            acc = b
            for w, v in zip(row, x):
                if w != 0.0:
                    acc = acc + w * v
            out.append(acc)
        if after_layer is not None:
            out = after_layer(layer, x, out)
        if layer < len(weights) - 1:
            out = [xp.maximum(v, slope * v) for v in out]
        x = out
    return x


@dataclass(frozen=True)
class Folded:
    """Everything ``specialize`` computed once, in one dtype: what an exporter reads.

    ``params``: each parameter as the formulas' constant (a float for width 1, else a (1, width)
    row); ``rotation``: rows (tangent, bitangent, normal) of the shading frame, or None for the
    geometric frame; ``constants``: positions computed once, (1, width); ``modules``: the folded
    modules by position."""

    params: dict[str, Any]
    rotation: torch.Tensor | None
    constants: dict[str, torch.Tensor]
    modules: dict[str, FoldedModule]

    def to(self, dtype: torch.dtype) -> "Folded":
        return Folded({k: v if isinstance(v, float) else v.to(dtype) for k, v in self.params.items()},
                      None if self.rotation is None else self.rotation.to(dtype),
                      {k: v.to(dtype) for k, v in self.constants.items()},
                      {k: m.to(dtype) for k, m in self.modules.items()})


class SpecializedBRDF:
    """``f_r = brdf(wi, wo)`` for one material: (n, 3) unit vectors in the local frame -> (n, 3),
    without the cosine factor, zero below either horizon, clipped at zero (as ``evaluate``).

    Computed in the inputs' dtype: float64 inputs get float64 throughout (the fold is done in
    float64 and kept as ``folded``), anything else float32 (the model's own precision)."""

    def __init__(self, model, params: MaterialParams | Mapping[str, Any]):
        self.model_name = model.name
        self.state = model.state
        self.formula = model.describe()
        self.expression = model.expression()  # the tree evaluated: the chosen alternatives substituted
        record = MaterialParams.of(params)
        values = model.specs.validate(model.complete_params(record.values), 1)
        latent = None
        if model.latent_dim and model.uses_latent:
            latent = model._check_latent(record.latent, 1)
        # the material's module weights: the shared ones plus its corrections (as evaluate adds them)
        weights = {k: w.detach() for k, w in model.neural.named_parameters()}
        weights.update({k: w.detach() for k, w in model.corrected_weights(record.corrections).items()})
        values = {k: v.detach().double() for k, v in values.items()}
        # Per-material inputs of term modules, as every module reads them (float64 for the fold).
        per_material = [model.module_specs.unit_vector(values)]
        if latent is not None:
            per_material.append(latent.detach().double())
        material_input = torch.cat(per_material, dim=-1)[0]
        params = {k: _constant(v[0]) for k, v in values.items()}
        modules: dict[str, FoldedModule] = {}
        constants: dict[str, torch.Tensor] = {}
        param_shading = Shading.of_params(params, TORCH)
        chosen = model.chosen_terms()
        for expr, digit in zip(model.graph.positions, model.digits):
            expr = chosen.get(expr.name, expr)
            if isinstance(expr, Term):
                if model.is_neural(digit):
                    module = _fold(expr.name, model.neural[expr.name], weights, material_input, expr.reads_directions)
                    if expr.reads_directions:
                        modules[expr.name] = module
                    else:  # a module of the parameters alone: its output is a constant
                        constants[expr.name] = module(torch.zeros(1, 0, dtype=torch.float64))
                elif not expr.reads_directions:
                    constants[expr.name] = _rows(expr.formula(param_shading), expr.width)
            else:
                if model.is_neural(digit):
                    modules[expr.name] = _fold(expr.name, model.neural[expr.name], weights, None, True)
                elif expr.left.name in constants and expr.right.name in constants:
                    left, right = constants[expr.left.name], constants[expr.right.name]
                    constants[expr.name] = left + right if expr.op == "+" else left * right
        self.folded = Folded(params, self._frame(values), constants, modules)
        self._kernels = {torch.float64: self.folded, torch.float32: self.folded.to(torch.float32)}

    @property
    def modules(self) -> dict[str, FoldedModule]:
        return self.folded.modules

    @property
    def constants(self) -> dict[str, torch.Tensor]:
        return self.folded.constants

    @staticmethod
    def _frame(values: Mapping[str, torch.Tensor]) -> torch.Tensor | None:
        """The rotation whose rows are the shading frame's (tangent, bitangent, normal)."""
        frame = frame_of(TORCH, values)
        return None if frame is None else torch.cat([axis.array for axis in frame])

    # -- evaluation ------------------------------------------------------------------------------
    @torch.no_grad()
    def __call__(self, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        wi, wo = torch.as_tensor(wi), torch.as_tensor(wo)
        if wi.ndim != 2 or wi.shape[1] != 3 or wi.shape != wo.shape:
            raise ValueError(f"wi and wo must both have shape (n, 3), got {tuple(wi.shape)} and {tuple(wo.shape)}")
        dtype = torch.float64 if wi.dtype == torch.float64 else torch.float32
        wi, wo = wi.to(dtype), wo.to(dtype)
        if wi.shape[0] <= CHUNK:
            return self._evaluate(wi, wo, self._kernels[dtype])
        out = torch.empty(wi.shape[0], 3, dtype=dtype)
        for lo in range(0, wi.shape[0], CHUNK):
            out[lo : lo + CHUNK] = self._evaluate(wi[lo : lo + CHUNK], wo[lo : lo + CHUNK], self._kernels[dtype])
        return out

    def _evaluate(self, wi: torch.Tensor, wo: torch.Tensor, k: Folded) -> torch.Tensor:
        rotate = (lambda w: w) if k.rotation is None else (lambda w: w @ k.rotation.t())
        s = shade(TORCH, BatchVec3(wi), BatchVec3(wo), BatchVec3(rotate(wi)), BatchVec3(rotate(wo)), k.params)
        directions = torch.cat([s.wi.array, s.wo.array], dim=-1) if k.modules else None
        n = wi.shape[0]

        def module(expr: Expr, folded: FoldedModule, operands) -> torch.Tensor:
            if operands is None:  # a term's module reads the directions
                return folded(directions)
            left, right = operands
            return folded(torch.cat([left.expand(n, expr.left.width), right.expand(n, expr.right.width)], dim=-1))

        out = walk(self.expression, k, constant=lambda expr, value: value,
                   formula=lambda term: _rows(term.formula(s), term.width).to(wi.dtype), module=module)
        return torch.where(s.above, out.expand(n, 3), 0.0).clamp_min(0.0)

    # -- cost --------------------------------------------------------------------------------------
    @property
    def n_neural_weights(self) -> int:
        return sum(w.numel() + b.numel() for m in self.modules.values() for w, b in m.layers)

    @property
    def flops_per_evaluation(self) -> int:
        """FLOPs of one evaluation: the folded modules exactly (``FoldedModule.flops``) plus the
        analytical part counted by running it once on the counting backend (``neuenh.ops.COUNT``)."""
        from .ops import count_flops

        analytic = count_flops(lambda xp, wi, wo: self._count(xp, wi, wo))
        return analytic + sum(m.flops for m in self.modules.values())

    def _count(self, xp, wi, wo):
        rotate = (lambda w: w) if self.folded.rotation is None else (lambda w: xp.rotate(self.folded.rotation, w))
        params = {k: v if isinstance(v, float) else xp.constant(v.shape[-1]) for k, v in self.folded.params.items()}
        s = shade(xp, wi, wo, rotate(wi), rotate(wo), params)
        value = walk(self.expression, self.folded, constant=lambda expr, v: xp.constant(v.shape[-1]),
                     formula=lambda term: term.formula(s),
                     module=lambda expr, folded, operands: xp.value(expr.width))  # counted exactly: FoldedModule.flops
        return xp.where(s.above, value, 0.0)

    def throughput(self, n: int = 100_000, seconds: float = 0.5, threads: int | None = 1) -> float:
        """Measured evaluations per second at batches of ``n`` random directions (on ``threads``
        torch threads; ``None`` keeps the current setting)."""
        generator = torch.Generator().manual_seed(0)
        wi, wo = (torch.nn.functional.normalize(torch.randn(n, 3, generator=generator).abs(), dim=1)
                  for _ in range(2))
        saved = torch.get_num_threads()
        if threads is not None:
            torch.set_num_threads(threads)
        try:
            self(wi, wo)  # warm up
            calls, start = 0, time.perf_counter()
            while (elapsed := time.perf_counter() - start) < seconds or calls < 3:
                self(wi, wo)
                calls += 1
        finally:
            torch.set_num_threads(saved)
        return calls * n / elapsed


def walk(expression: Expr, folded: Folded, *, constant: Callable[[Expr, torch.Tensor], V],
         formula: Callable[[Term], V], module: Callable[[Expr, FoldedModule, tuple[V, V] | None], V]) -> V:
    """A specialized material's value, bottom-up, on any backend (``graph.fold``): what the torch
    kernel, the FLOP count, GLSL, ONNX and Dr.Jit each make of the same expression.

    * a position computed once (``folded.constants``): ``constant(expr, value (1, width))``;
    * a term a module replaces: ``module(term, folded_module, None)`` (it reads the 6 shading-frame
      directions); another term: ``formula(term)``, its formula on the backend;
    * an operator a module replaces: ``module(op, folded_module, (left, right))``; another operator:
      its ``+`` or ``*`` of the operands' values.

    ``module`` is the one place a backend runs an MLP (its layers: ``FoldedModule.layers``)."""

    def term(leaf: Term) -> V:
        replaced = folded.modules.get(leaf.name)
        return formula(leaf) if replaced is None else module(leaf, replaced, None)

    def operator(op: Operator, left: V, right: V) -> V:
        replaced = folded.modules.get(op.name)
        return apply(op, left, right) if replaced is None else module(op, replaced, (left, right))

    def given(expr: Expr) -> V | None:
        value = folded.constants.get(expr.name)
        return None if value is None else constant(expr, value)

    return fold(expression, term, operator, given)


def _constant(value: torch.Tensor):
    """A parameter as the formulas' constant: a Python float for width 1, else a (1, width) row."""
    return float(value[0]) if value.numel() == 1 else value.reshape(1, -1)


def _rows(value, width: int) -> torch.Tensor:
    """A term's value as a tensor broadcastable to (n, width) (a constant becomes (1, width))."""
    if isinstance(value, torch.Tensor):
        return value
    return torch.full((1, width), float(value), dtype=torch.float64)


def _fold(position: str, module, weights: Mapping[str, torch.Tensor], material_input: torch.Tensor | None,
          reads_per_sample: bool) -> FoldedModule:
    """``module`` (its weights ``weights[f"{position}.layers.{i}.weight"]``, ``...bias``: the
    material's) with ``material_input`` (the leading inputs of its first layer) folded into the
    first-layer bias; its first layer then reads the remaining inputs (none if not per-sample)."""
    layers = [(weights[f"{position}.layers.{i}.weight"].double(), weights[f"{position}.layers.{i}.bias"].double())
              for i in range(len(module.layers))]
    weight, bias = layers[0]
    if material_input is not None:
        k = material_input.shape[0]
        bias = bias + weight[:, :k] @ material_input
        weight = weight[:, k:] if reads_per_sample else weight[:, :0]
    layers[0] = (weight, bias)
    return FoldedModule(position, tuple((w.contiguous(), b) for w, b in layers), module.negative_slope)
