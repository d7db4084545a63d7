"""A fit's kernel compiled by Dr.Jit: each step's forward and reverse pass as one fused CPU kernel.

``RowKernel`` runs a fit step as ~900 torch operations, each a pass over (rows x slots, 32)
activations in memory; a step of the latent fit costs what those passes cost, not what its FLOPs
cost (docs/BENCHMARKS.md, "The latent fit's step under `torch.compile`"). ``JitRowKernel`` computes
the same losses and gradients with the model's frozen modules unrolled into Dr.Jit kernels (LLVM,
the machine's vector width), each sample's activations in registers: the forward pass, keeping what
the reverse pass reads, and the reverse pass, the step recorded once by ``drjit.freeze`` and replayed
after (docs/BENCHMARKS.md, "Stop 65").

The work is split where it is cheap to split (as ``BRDFModel.forward_indexed`` splits it):

* torch, per row and differentiable: the physical values, the shading frame, the terms that read
  no direction, and each module's first-layer bias with the row's 12 analytical inputs and latent
  code folded in (``b1 + W1[:, :P] @ [unit params, latent]``, as ``neuenh.specialize`` folds one
  material);
* Dr.Jit, per sample: those per-row values gathered, the shading geometry, the term formulas
  (``neuenh.ops``' vocabulary on Dr.Jit arrays) and the modules with their remaining weights as
  constants, the log-L1 (or its Charbonnier surrogate) and each sample's gradient with respect to
  its row's values;
* torch again: those gradients summed over each row's samples, in a fixed order (a scatter into the
  rows' values would add them in the order the threads ran, and a fit would not repeat), and carried
  back to the rows ``x`` through the first part.

Rows with module corrections (the adaptive fit's ``last-layer``, ``low-rank``, ``rank-8``, ``full``)
add each corrected layer's per-row factors (``W`` or ``U V``, and ``b``) to its constant weights in the
kernel, gathered per sample but outside Dr.Jit's derivative: their gradient is each row's sum over its
samples of the layer's output adjoint times its input, ``G^T X``, one batched matrix product in torch
from the two the kernel hands back (the adjoint read off a zero added to the layer's output), then
carried to ``U`` and ``V`` by torch (a scatter of every factor's gradient from every sample would
cost an atomic add per factor and sample). The gathers still cost a read per factor and sample, so
``row_kernel`` gives rows of many factors (``rank-8``, auto's union of candidates) to torch.

``available()`` says whether Dr.Jit and a usable libLLVM are installed; the kernel is an
optional speed-up (the ``neuenh[export]`` extra already brings Dr.Jit), never a requirement.
"""

from __future__ import annotations

import gc
import itertools
from functools import partial
from typing import Any

import numpy as np
import torch

from ..graph import Operator, Term, apply, fold
from ..llvm import point_drjit_at_libllvm
from ..ops import TORCH, DrJitArrayOps
from ..shading import Shading, frame_of, shade, to_frame
from ..specialize import FoldedModule, unrolled_mlp
from .kernel import (
    CHUNK_SLOTS,
    LayerCorrection,
    RowKernel,
    RowLosses,
    RowSpace,
    dense_deltas,
    row_view,
)
from .layout import RowLayout

# A fit protocol's ``kernel``: "torch" (``RowKernel``), "jit" (``JitRowKernel`` where it is faster, else torch),
# "auto" (jit for fits of at least ``JIT_MIN_WORK``, torch for smaller ones).
KERNELS = ("torch", "jit", "auto")
# Measurement-epochs (``FitProtocol.work``) from which "auto" takes the jit kernel. The kernel holds the modules'
# weights as constants, so each model's first fit on a machine compiles (the shipped model's latent fit: four kernels,
# ~4 s, for any number of materials; then read from Dr.Jit's disk cache), which a fit saves back at ~3 us a
# measurement-epoch (its 3,000-sample fit, 900,000 of them: 5.6 s on torch, 2.7 s on jit; docs/BENCHMARKS.md,
# "Stop 68"). Below this (a fit of ~700 samples at 300 epochs, a second or two on torch) the fit is a quick look or a
# test's, and a compile would cost more than every such fit of that model saves.
JIT_MIN_WORK = 200_000
# Per-row correction factors a sample may read for the jit kernel to be the faster: each is a gather per
# sample, and a step of the shipped model's rows (one thread, 4 x 3,000 and 8 x 10,000 slots) took, jit over
# torch, 0.20-0.32 without corrections, 0.34-0.40 with its last layers (198 a sample), 0.60-0.85 at rank 2
# (1,022), 1.29-1.37 at rank 8 (3,014) (docs/BENCHMARKS.md, "Stop 66").
JIT_FACTOR_READS = 2000
# Samples a call (rows x slots) from which ``_row_sums`` sums each gradient column where it lies rather than
# stacking them first: below it the sums' fixed cost per column is the larger (70 columns of the shipped model
# at one thread: 1 x 10,000 samples 0.69 ms stacked against 0.72 ms, 1 x 20,000 1.01 against 0.86 ms, 4 x 20,000
# 3.29 against 1.62 ms; docs/BENCHMARKS.md, "Stop 82").
COLUMN_SUM_SAMPLES = 16_384
_STATE: dict[str, Any] = {}


def row_kernel(model, space: RowSpace, kernel: str = "torch", work: int | None = None):
    """The kernel a fit protocol's ``kernel`` names for ``model``'s rows in ``space``: ``JitRowKernel``
    for "jit", and for "auto" when the fit's ``work`` (measurement-epochs) is at least ``JIT_MIN_WORK``,
    when Dr.Jit is ``available()`` and a sample reads at most ``JIT_FACTOR_READS`` of the rows'
    correction factors; else ``RowKernel``."""
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {', '.join(KERNELS)}, got {kernel!r}")
    if kernel == "auto":
        kernel = "jit" if work is not None and work >= JIT_MIN_WORK else "torch"
    if kernel == "jit" and available():
        jit = JitRowKernel(model, space)
        if jit.factor_reads <= JIT_FACTOR_READS:
            return jit
    return RowKernel(model, space)


def available() -> bool:
    """Whether Dr.Jit's LLVM backend can run here (imported and initialised once per process)."""
    if "ok" not in _STATE:
        try:
            if not point_drjit_at_libllvm():
                raise ImportError("no libLLVM")
            import drjit as dr
            import drjit.llvm.ad  # noqa: F401

            _STATE["ok"] = bool(dr.has_backend(dr.JitBackend.LLVM))
        except (ImportError, RuntimeError, OSError):
            _STATE["ok"] = False
        if _STATE["ok"] and "threads" in _STATE:
            dr.set_thread_count(_STATE["threads"])
    return _STATE["ok"]


def set_jit_threads(threads: int) -> None:
    """Dr.Jit's thread pool, in which the jit kernel runs, to ``threads``: now if Dr.Jit is initialised,
    else when ``available()`` first initialises it, so a process that never takes the jit kernel never
    imports Dr.Jit. Process-wide: set it where the process is the fit's own (``neuenh fit --threads``, a
    fit's worker processes); Mitsuba in the same process needs more than one (with one, its EXR reader
    waits on a task of the pool forever)."""
    _STATE["threads"] = threads
    if _STATE.get("ok"):
        import drjit as dr

        dr.set_thread_count(threads)


def set_fit_threads(threads: int) -> None:
    """A process's fits to ``threads``: torch's and Dr.Jit's (``set_jit_threads``), whichever kernel its
    protocols' rows take."""
    torch.set_num_threads(threads)
    set_jit_threads(threads)


def _log1p(x):
    """log(1 + x) to float32's precision for small x, as torch.log1p (Dr.Jit has none): log(u) x / (u - 1)
    with u = 1 + x rounded (Goldberg, "What every computer scientist should know about floating-point
    arithmetic", 1991, Theorem 4), x itself where u rounds to 1. log(1 + x) alone loses x's digits below
    1 + x's ulp: a relative error of ~6e-8 / x, 1 % of a dark material's residuals at x ~ 1e-5."""
    import drjit as dr

    u = 1.0 + x
    return dr.select(u == 1.0, x, dr.log(u) * (x / (u - 1.0)))


def _column_map(values: dict[str, torch.Tensor]) -> dict[str, tuple[int, int]]:
    """Each (rows, width) value's first column and width in the values side by side, in ``values``' order."""
    widths = [value.shape[1] for value in values.values()]
    return dict(zip(values, zip(itertools.accumulate([0, *widths[:-1]]), widths)))


def _sample_columns(columns: list, rows: int, slots: int) -> torch.Tensor:
    """Dr.Jit arrays of a value per sample as one (columns, rows, slots) tensor."""
    return torch.from_numpy(np.stack([column.numpy() for column in columns])).reshape(-1, rows, slots)


def _row_sums(columns: list, rows: int, slots: int) -> torch.Tensor:
    """(rows, columns) float32: each Dr.Jit array of a value per sample (row by row) summed over each row's
    slots by torch (a cascade sum, in a fixed order), the same sums to the bit however they are taken.

    One sum of the columns stacked first costs a copy of them all; above ``COLUMN_SUM_SAMPLES`` samples a
    call that copy costs more than a sum of each column where Dr.Jit left it (the latent fit of 100,000
    samples: docs/BENCHMARKS.md, "Stop 82"). Each row's sum is then the same reduction of the same
    values, one thread's: torch splits a reduction between threads over its outputs, but over the summed
    slots themselves when it has only one output (a column of one row), so the column by column sums
    are taken only at one torch thread (a fit's process: ``set_fit_threads``)."""
    if rows * slots < COLUMN_SUM_SAMPLES or torch.get_num_threads() != 1:
        return _sample_columns(columns, rows, slots).sum(2).t()
    return torch.stack([torch.from_numpy(column.numpy()).view(rows, slots).sum(1) for column in columns], 1)


class JitRowKernel:
    """``RowKernel``'s losses and gradients (the same call; module doc), computed by one Dr.Jit kernel a
    step in Dr.Jit's thread pool (all cores unless ``set_jit_threads``). Equal to ``RowKernel``'s up to
    float32 rounding."""

    def __init__(self, model, space: RowSpace):
        if not available():
            raise RuntimeError("Dr.Jit's LLVM backend is not available (pip install drjit; libLLVM 17 or newer)")
        self.model, self.space = model, space
        self.dtype = torch.float32
        self._plan()
        self._frozen = {}
        self._columns: dict[str, tuple[int, int]] | None = None  # per-row values: name -> (first column, width)
        self._factor_columns: dict[str, tuple[int, int]] | None = None  # the same for the corrections' factors
        self._inputs: tuple[RowLayout, tuple] | None = None  # the last layout and its samples as Dr.Jit arrays

    # -- what runs per row (torch) and what per sample (Dr.Jit) ----------------------------------------
    def _plan(self) -> None:
        """Which positions are per-row constants, which modules run per sample (their constant layers,
        and whether their first layer reads the per-material inputs), in the model's expression."""
        model = self.model
        self.expression = model.expression()
        self.const_positions: dict[str, str] = {}  # position -> "module", "formula" or "operator"
        self.modules: dict[str, tuple[tuple[list, list, float], bool]] = {}  # layers as floats, bias per row
        chosen = model.chosen_terms()
        for expr, digit in zip(model.graph.positions, model.digits):
            expr = chosen.get(expr.name, expr)
            neural = model.is_neural(digit)
            if isinstance(expr, Term):
                if neural and expr.reads_directions:
                    self.modules[expr.name] = self._constant_layers(expr.name, folded=True)
                elif not expr.reads_directions:
                    self.const_positions[expr.name] = "module" if neural else "formula"
            elif neural:
                self.modules[expr.name] = self._constant_layers(expr.name, folded=False)
            elif expr.left.name in self.const_positions and expr.right.name in self.const_positions:
                self.const_positions[expr.name] = "operator"
        # the corrections of each layer a sample runs, and the layers' columns a sample reads (the first
        # layer of a folded module: its per-sample inputs only; the per-row part and bias are in its bias)
        self.corrected: dict[tuple[str, int], list[tuple[int, LayerCorrection]]] = {}
        for i, c in enumerate(self.space.corrections):
            if c.position in self.modules:
                self.corrected.setdefault((c.position, c.layer), []).append((i, c))
        # the per-row factors a sample reads (``row_kernel`` weighs them against JIT_FACTOR_READS)
        one_row = self.space.factors(torch.zeros(1, self.space.dim))
        self.factor_reads = sum(f.shape[1] for f in self._sample_factors(one_row).values())

    def _row_inputs(self, position: str, layer: int) -> int:
        """How many of a layer's input columns are the row's (folded into its bias per row): the
        material inputs for a folded module's first layer, else none."""
        return self._material_inputs() if layer == 0 and self.modules[position][1] else 0

    def _constant_layers(self, position: str, folded: bool):
        """A module's layers as Python floats (``FoldedModule.as_floats``; the first layer's per-sample
        columns only when the row's inputs are folded into its bias), and whether that bias is per row."""
        module = self.model.neural[position]
        layers = [(layer.weight.detach().double(), layer.bias.detach().double()) for layer in module.layers]
        if folded:
            layers[0] = (layers[0][0][:, self._material_inputs():], layers[0][1])
        return FoldedModule(position, tuple(layers), module.negative_slope).as_floats(), folded

    def _material_inputs(self) -> int:
        model = self.model
        return sum(spec.width for spec in model.module_specs) + (model.latent_dim if model.uses_latent else 0)

    def _per_row(self, x: torch.Tensor, deltas: dict) -> dict[str, torch.Tensor]:
        """Everything a sample reads from its row, (rows, width) each, as a differentiable function of
        ``x`` (and its corrections' ``deltas``, ``RowSpace.deltas``): ``param:NAME``, ``frame`` (9: tangent,
        bitangent, normal), ``const:POS``, ``bias:POS``."""
        model = self.model
        values, latent = self.space.values(x)
        view = row_view(model, x.shape[0], deltas) if deltas else model  # per-row modules where corrected
        out = {f"param:{k}": v for k, v in values.items()}
        frame = frame_of(TORCH, values)
        if frame is not None:
            out["frame"] = torch.cat([axis.array for axis in frame], dim=1)
        per_material = Shading.of_params(values, TORCH)
        rows = x.shape[0]
        material_input = None
        if any(folded for _, folded in self.modules.values()):
            parts = [model.module_specs.unit_vector(values)]
            if model.uses_latent:
                parts.append(latent)
            material_input = torch.cat(parts, dim=1)
        constants: dict[str, torch.Tensor] = {}
        chosen = model.chosen_terms()
        for expr in model.graph.positions:
            expr = chosen.get(expr.name, expr)
            if expr.name in self.modules and self.modules[expr.name][1]:
                out[f"bias:{expr.name}"] = self._first_bias(expr.name, material_input, deltas)
            kind = self.const_positions.get(expr.name)
            if kind == "module":
                value = view.neural[expr.name](material_input)
            elif kind == "formula":
                value = torch.as_tensor(expr.formula(per_material), dtype=x.dtype)
            elif kind == "operator":
                left, right = constants[expr.left.name], constants[expr.right.name]
                value = left + right if expr.op == "+" else left * right
            else:
                continue
            constants[expr.name] = (value.reshape(1, 1) if value.ndim == 0 else value).expand(rows, expr.width)
        out.update({f"const:{k}": v for k, v in constants.items()})
        return out

    def _first_bias(self, position: str, material_input: torch.Tensor, deltas: dict) -> torch.Tensor:
        """(rows, out): a folded module's first-layer bias with the row's inputs folded in, ``b + W[:, :k] m``,
        plus ``db + dW[:, :k] m`` of each correction of that layer."""
        k = material_input.shape[1]
        first = self.model.neural[position].layers[0]
        bias = torch.addmm(first.bias, material_input, first.weight[:, :k].t())
        for _, c in self.corrected.get((position, 0), ()):
            weight, bias_delta = deltas[c]
            bias = bias + bias_delta + torch.bmm(weight[:, :, :k], material_input.unsqueeze(2)).squeeze(2)
        return bias

    def _sample_factors(self, factors: dict) -> dict[str, torch.Tensor]:
        """(rows, width) each, detached: the factors a sample's corrected layers read, ``corr:I:W``
        (dense) or ``corr:I:U`` and ``corr:I:V`` (low rank), and ``corr:I:b`` (not for a folded first
        layer, whose bias is per row), ``I`` the correction's index in the space."""
        out = {}
        for (position, layer), corrections in self.corrected.items():
            k = self._row_inputs(position, layer)
            for i, c in corrections:
                f = [t.detach() for t in factors[c]]
                if c.rank is None:
                    out[f"corr:{i}:W"] = f[0][:, :, k:].flatten(1)
                else:
                    out[f"corr:{i}:U"], out[f"corr:{i}:V"] = f[0].flatten(1), f[1][:, :, k:].flatten(1)
                if not k:
                    out[f"corr:{i}:b"] = f[-1]
        return out

    def _sample_deltas(self, deltas: dict) -> dict[tuple[str, int], tuple[torch.Tensor, torch.Tensor | None]]:
        """Each corrected layer's summed delta (``RowSpace.deltas``) over the columns a sample reads,
        (rows, out, in), and its bias delta (rows, out) (None for a folded first layer's)."""
        out = {}
        for (position, layer), corrections in self.corrected.items():
            k = self._row_inputs(position, layer)
            weight = sum(deltas[c][0][:, :, k:] for _, c in corrections)
            out[position, layer] = (weight, None if k else sum(deltas[c][1] for _, c in corrections))
        return out

    # -- the per-sample kernel (Dr.Jit) ------------------------------------------------------------------
    def _loss(self, table, factor_table, wi, wo, f_r, row, eps: float | None, taps: dict | None,
              leaves: list | None):
        """Each sample's loss (log-L1, ``train.log_l1``) and fitted value (the loss, or its Charbonnier
        surrogate with ``eps``, as ``RowKernel``), on Dr.Jit arrays; ``table``: the per-row values, row
        by row (``_columns``: each name's first column and width in a row); ``factor_table`` the same
        for the corrections' factors (``_factor_columns``), read outside the derivative. ``taps``, when
        given, gets each corrected layer's inputs and the zeros added to its outputs, with their
        derivative enabled: their gradient is the layer's output adjoint. ``leaves``, when given, gets
        every column's gathered values, with their derivative enabled: their gradient is each sample's
        share of the row's."""
        import drjit as dr
        from drjit.llvm.ad import Array3f, Float

        xp = DrJitArrayOps()
        def gather(source, columns: dict[str, tuple[int, int]]) -> dict[str, list]:
            # row-major, so the kernel's code reads no count of rows: one compiled kernel serves fits of
            # any number of rows and starts (a count in it cost a compile of seconds for each one)
            start = row * sum(width for _, width in columns.values())
            return {name: [dr.gather(Float, source, start + (first + j)) for j in range(width)]
                    for name, (first, width) in columns.items()}

        lane = gather(table, self._columns)  # each sample's copies are leaves (``leaves``): no scatter back
        factor = gather(factor_table, self._factor_columns)  # no derivative: factor_table's is never enabled
        if leaves is not None:
            for values in lane.values():
                dr.enable_grad(values)
                leaves.extend(values)

        def vec(values):
            return values[0] if len(values) == 1 else (Array3f(*values) if len(values) == 3 else tuple(values))

        params = {name[6:]: vec(v) for name, v in lane.items() if name.startswith("param:")}
        if "frame" in lane:
            f = lane["frame"]
            frame = (Array3f(*f[0:3]), Array3f(*f[3:6]), Array3f(*f[6:9]))
            s = shade(xp, wi, wo, to_frame(xp, wi, frame), to_frame(xp, wo, frame), params)
        else:
            s = shade(xp, wi, wo, wi, wo, params)
        directions = [s.wi.x, s.wi.y, s.wi.z, s.wo.x, s.wo.y, s.wo.z]

        def corrected(name: str, layer: int, inputs: list, out: list) -> list:
            """A layer's outputs with its rows' corrections added: ``W x`` or ``U (V x)``, and ``b``."""
            for i, c in self.corrected.get((name, layer), ()):
                if c.rank is None:
                    w = factor[f"corr:{i}:W"]
                    out = [o + sum(w[r * len(inputs) + j] * v for j, v in enumerate(inputs)) for r, o in enumerate(out)]
                else:
                    u, v_ = factor[f"corr:{i}:U"], factor[f"corr:{i}:V"]
                    z = [sum(v_[q * len(inputs) + j] * v for j, v in enumerate(inputs)) for q in range(c.rank)]
                    out = [o + sum(u[r * c.rank + q] * zq for q, zq in enumerate(z)) for r, o in enumerate(out)]
                if f"corr:{i}:b" in factor:
                    out = [o + b for o, b in zip(out, factor[f"corr:{i}:b"])]
            if taps is not None and (name, layer) in self.corrected:
                zeros = [dr.zeros(Float, dr.width(row)) for _ in out]
                dr.enable_grad(zeros)
                taps[name, layer] = ([dr.detach(v) for v in inputs], zeros)
                out = [o + h for o, h in zip(out, zeros)]
            return out

        def mlp(name: str, inputs: list):
            floats, folded = self.modules[name]
            x = unrolled_mlp(xp, floats, inputs, lane[f"bias:{name}"] if folded else None, partial(corrected, name))
            return x[0] if len(x) == 1 else Array3f(*x)

        def flat(value, width: int) -> list:
            if width == 1:
                return [value]
            return [value.x, value.y, value.z] if isinstance(value, Array3f) else [value] * 3

        def term(leaf: Term):
            return mlp(leaf.name, directions) if leaf.name in self.modules else leaf.formula(s)

        def operator(op: Operator, left, right):
            if op.name not in self.modules:
                return apply(op, left, right)
            return mlp(op.name, flat(left, op.left.width) + flat(right, op.right.width))

        def given(expr):
            if expr.name not in self.const_positions:
                return None
            return vec(lane[f"const:{expr.name}"])

        value = fold(self.expression, term, operator, given)
        value = Array3f(value) if not isinstance(value, Array3f) else value
        pred = dr.select(s.above, value, 0.0)
        cos_i = dr.maximum(wi.z, 0.0)
        loss, fitted = Float(0.0), Float(0.0)
        for c in range(3):
            p, t = pred[c] * cos_i, f_r[c] * cos_i
            r = _log1p(t) - dr.sign(p) * _log1p(dr.abs(p))  # train.log_residual
            loss += dr.abs(r) / 3.0
            fitted += (dr.abs(r) if eps is None else dr.sqrt(r * r + eps * eps) - eps) / 3.0
        return loss, fitted

    def _step(self, table, factor_table, wi, wo, f_r, row, weight, eps: float | None, grad: bool):
        """Each sample's loss and fitted value (the loss or its surrogate) and, with ``grad``, each
        sample's gradient of its weighted fitted value with respect to every column of ``table`` (its
        row's values: ``_pass`` sums them per row) and the corrected layers' taps: per layer
        (``corrected`` order) its inputs, then its output adjoint, a column of samples each."""
        import drjit as dr

        taps = {} if grad and self.corrected else None
        leaves = [] if grad else None
        loss, fitted = self._loss(table, factor_table, wi, wo, f_r, row, eps, taps, leaves)
        gradient = tapped = None
        if grad:
            dr.backward(fitted * weight)  # every sample seeded with 1: the gradient of their sum, no reduction
            gradient = [dr.grad(v) for v in leaves]
        if taps:
            tapped = [c for key in self.corrected for c in taps[key][0] + [dr.grad(h) for h in taps[key][1]]]
        loss, fitted = dr.detach(loss), dr.detach(fitted)
        dr.eval(loss, fitted, gradient, tapped)
        return loss, fitted, gradient, tapped

    # -- RowKernel's call ------------------------------------------------------------------------------------
    def __call__(self, x: torch.Tensor, layout: RowLayout, *, grad: bool = True,
                 prior_strength: torch.Tensor | None = None, surrogate_eps: float | None = None,
                 chunk_slots: int = CHUNK_SLOTS) -> RowLosses:
        """``RowKernel.__call__``'s losses (``prior_strength`` (rows,) weighs ``RowSpace.prior`` of rows
        with corrections); a layout of more than ``chunk_slots`` slots a row is evaluated a chunk at a
        time, the gradients summed, as ``RowKernel`` does (the reverse pass keeps each sample's
        intermediates)."""
        if chunk_slots < 1:
            raise ValueError(f"chunk_slots must be at least 1, got {chunk_slots}")
        x = x.detach().to(self.dtype)
        weight = layout.train.sum(1).clamp_min(1e-12)
        parts = [self._pass(x, layout.chunk(lo, min(lo + chunk_slots, layout.slots)), weight, grad, surrogate_eps)
                 for lo in range(0, layout.slots, chunk_slots)]
        per = torch.cat([part[0] for part in parts], 1)
        fitted = torch.cat([part[1] for part in parts], 1)
        g = sum(part[2] for part in parts) if grad else None
        train = (per * layout.train).sum(1) / layout.train.sum(1).double().clamp_min(1e-12)
        objective = (fitted * layout.train).sum(1) / weight.double()
        if prior_strength is not None and self.space.corrections:
            penalty, g_penalty = self.space.penalty(x, prior_strength, grad)
            objective = objective + penalty.double()
            g = g + g_penalty if grad else g
        val_weight = layout.val.sum(1).double()
        val = torch.where(val_weight > 0, (per * layout.val).sum(1) / val_weight.clamp_min(1e-12), torch.nan)
        return RowLosses(train, val, objective, g, per)

    def _samples(self, layout: RowLayout, weight: torch.Tensor) -> tuple:
        """What the kernel reads per sample of ``layout`` as Dr.Jit arrays: its directions and targets,
        its row, and its weight in its row's objective. Made once per layout (an Adam run's steps are
        calls on one layout): a layout always comes with the same ``weight``, its own rows' train sums,
        or its whole layout's for a chunk, which ``__call__`` makes anew at every call."""
        from drjit.llvm.ad import Array3f, Float, UInt32

        if self._inputs is None or self._inputs[0] is not layout:
            lanes = lambda t: Array3f(*(Float(t[:, j].contiguous()) for j in range(3)))
            row = UInt32(torch.arange(layout.rows, dtype=torch.int32).repeat_interleave(layout.slots))
            w = Float((layout.train / weight[:, None]).reshape(-1).contiguous())
            self._inputs = (layout, (lanes(layout.wi), lanes(layout.wo), lanes(layout.f_r), row, w))
        return self._inputs[1]

    def _pass(self, x: torch.Tensor, layout: RowLayout, weight: torch.Tensor, grad: bool, eps: float | None
              ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """One kernel call over ``layout``: each slot's loss and fitted value (rows, slots) float64 and the
        gradient (rows, dim) of the sum of its train slots' fitted values over each row's ``weight``."""
        import drjit as dr
        from drjit.llvm.ad import Float

        rows, slots = layout.rows, layout.slots
        with torch.enable_grad() if grad else torch.no_grad():
            leaf = x.clone().requires_grad_(grad)
            factors = self.space.factors(leaf)
            deltas = dense_deltas(factors)
            per_row = self._per_row(leaf, deltas)
            if self._columns is None:  # the same names and widths at every call
                self._columns = _column_map(dict(sorted(per_row.items())))
            values = torch.cat([per_row[name] for name in self._columns], dim=1)  # (rows, columns)
            table = Float(values.detach().contiguous().reshape(-1))  # row by row (``_loss``)
            sample_factors = self._sample_factors(factors)
            if self._factor_columns is None:
                self._factor_columns = _column_map(sample_factors)
            factor_table = Float(torch.cat([sample_factors[name] for name in self._factor_columns], dim=1)
                                 .contiguous().reshape(-1) if sample_factors else torch.zeros(1))
            # recorded at a shape's first call, replayed after (drjit.freeze; one per shape: a recording's
            # reverse pass is bound to the sizes it saw)
            key = (eps, grad, rows, slots)
            if key not in self._frozen:
                self._frozen[key] = dr.freeze(lambda t, c, a, b, y, r, ww: self._step(t, c, a, b, y, r, ww, eps, grad))
            # Python's cycle collector stays out of the call: an array it frees while a step is being
            # recorded enqueues a host function, which a recording cannot hold (Dr.Jit aborts the process).
            collecting = gc.isenabled()
            gc.disable()
            try:
                loss, fitted, gradient, tapped = self._frozen[key](table, factor_table, *self._samples(layout, weight))
            finally:
                if collecting:
                    gc.enable()
            g = None
            if grad:
                # each row's sum over its samples, in a fixed order (module doc)
                cotangent = _row_sums(gradient, rows, slots)
                outputs, cotangents = [values], [cotangent]
                if self.corrected:  # each corrected layer's per-row gradient: sum over samples of G x^T
                    columns = _sample_columns(tapped, rows, slots)
                    at = 0
                    for weight_delta, bias_delta in self._sample_deltas(deltas).values():
                        n_out, n_in = weight_delta.shape[1:]
                        inputs, adjoint = columns[at : at + n_in], columns[at + n_in : at + n_in + n_out]
                        at += n_in + n_out
                        outputs.append(weight_delta)
                        cotangents.append(torch.bmm(adjoint.permute(1, 0, 2), inputs.permute(1, 2, 0)))
                        if bias_delta is not None:
                            outputs.append(bias_delta)
                            cotangents.append(adjoint.sum(2).t())
                torch.autograd.backward(outputs, cotangents)
                g = leaf.grad.detach()
        as_rows = lambda values: torch.from_numpy(values.numpy()).double().reshape(rows, slots)
        return as_rows(loss), as_rows(fitted), g
