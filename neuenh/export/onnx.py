"""ONNX graphs (``neuenh export --format onnx``): one material specialized, and the generic model.

Both graphs are opset 18, float32, with a dynamic batch dimension ``n``; ``wi``, ``wo`` are (n, 3)
unit vectors in the local frame (z = geometric normal, ARCHITECTURE §4) and the output ``f_r`` (n, 3) is
the BRDF without the cosine factor, exactly 0 below either horizon, clamped at 0:

* ``material_graph(specialized)``: inputs ``wi``, ``wo``; the specialized evaluator
  (``SpecializedBRDF``, its float32 kernel ``folded``): the shading frame as one 3x3 ``MatMul``,
  parameter-only terms as constants, the modules' first layers reading the 6 direction inputs;
* ``generic_graph(model)``: inputs ``wi``, ``wo`` and one per parameter, in ``model.param_names``
  order, each (n, width) or (1, width) (broadcast to every row), physical values inside their
  ranges (not checked: the graph is ``BRDFModel.forward``, what ``evaluate`` runs after its
  checks), plus ``latent`` (n or 1, latent_dim) when a module replaces a term; equals
  ``model.evaluate``.

Both carry ``metadata_props``: ``model``, ``state``, ``formula``, ``neuenh_version``, ``inputs``
(JSON: name -> shape) and, for a material, ``material``; ``doc_string`` says the same in words.
``write`` is the exporter entry point (``neuenh.export``): ``NAME.onnx`` per material and
``MODEL-generic.onnx``, each written atomically.

How the graphs are built. Not by ``torch.onnx.export`` — both exporters were tried on torch 2.13:
the dynamo exporter (``torch.export``) gives a clean graph (62 nodes for the shipped enhanced GGX)
but takes 1.5-2 s per graph (about 5 minutes for the 200 materials of the shipped model, and most
of a test run); the TorchScript exporter takes 0.1 s but is deprecated since torch 2.9 and leaves
Cast/Shape/Expand/Constant clutter (203 nodes). Instead the formulas run on a third backend of the
``neuenh.ops`` vocabulary whose values are ONNX values (``_OnnxOps``): every vocabulary function
and arithmetic operator appends the ONNX node of what torch computes (``1 / x`` is ``Reciprocal``
then ``Mul`` as in torch, ``x ** 2`` a ``Mul``, ``addmm`` a ``Gemm``), Python floats are still folded
by Python, identical nodes are built once. A graph takes milliseconds, depends on no torch
exporter, and runs the torch path's ops in its order, so onnxruntime agrees with torch to float32
rounding (tests). The graph walks below mirror ``SpecializedBRDF._evaluate`` and
``BRDFModel.forward``; the tests compare them with both.

Imports ``onnx`` (the ``neuenh[export]`` extra), not onnxruntime; neither Ray, FastAPI nor SQL.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import onnx
import torch
from onnx import TensorProto, helper, numpy_helper

from .. import __version__
from ..files import atomic_write
from ..graph import Term
from ..materials import LATENT_NAME, MaterialParams
from ..model import BRDFModel
from ..ops import BatchVec3, EmittingOps, _is_const
from ..shading import make_shading, shade
from ..specialize import FoldedModule, SpecializedBRDF, walk

__all__ = ["OPSET", "file_stem", "generic_graph", "material_graph", "nbrdf_graph", "write", "write_nbrdf"]

OPSET = 18
BATCH = "n"  # the dynamic batch dimension of wi, wo and f_r
PARAM_ROWS = "n_or_1"  # a generic graph's parameter rows: one per sample, or one for all
GENERIC_SUFFIX = "-generic"


# -- the graph under construction ---------------------------------------------------------------
class _Builder:
    """Nodes and initializers of one graph. ``op`` builds each distinct (op, inputs, attributes)
    once; names are numbered in build order, so the same model gives the same bytes."""

    def __init__(self):
        self.nodes: list[onnx.NodeProto] = []
        self.initializers: list[onnx.TensorProto] = []
        self._memo: dict[tuple, str] = {}

    def constant(self, array: np.ndarray) -> str:
        array = np.ascontiguousarray(array)
        key = ("const", array.dtype.str, array.shape, array.tobytes())
        if key not in self._memo:
            name = f"c{len(self.initializers)}"
            self.initializers.append(numpy_helper.from_array(array, name))
            self._memo[key] = name
        return self._memo[key]

    def op(self, op_type: str, *inputs: str, output: str | None = None, **attributes) -> str:
        key = (op_type, inputs, tuple(sorted(attributes.items())))
        if output is None and key in self._memo:
            return self._memo[key]
        name = output or f"v{len(self.nodes)}"
        self.nodes.append(helper.make_node(op_type, list(inputs), [name], name=f"{op_type}_{len(self.nodes)}",
                                           **attributes))
        self._memo.setdefault(key, name)
        return name


class _Value:
    """A value of the graph: ``name`` with ``width`` columns; ``per_sample`` values have n rows,
    the others one (a constant row or a scalar, broadcast like torch's)."""

    __slots__ = ("b", "name", "width", "per_sample")
    __array_ufunc__ = None

    def __init__(self, b: _Builder, name: str, width: int, per_sample: bool):
        self.b, self.name, self.width, self.per_sample = b, name, width, per_sample

    # -- building ------------------------------------------------------------------------------
    def _lift(self, x) -> "_Value":
        return x if isinstance(x, _Value) else _scalar(self.b, float(x))

    def _binary(self, op_type: str, left, right) -> "_Value":
        if not all(isinstance(v, (_Value, int, float)) for v in (left, right)):
            return NotImplemented  # e.g. ``value * vec3``: BatchVec3.__rmul__ takes it
        left, right = self._lift(left), self._lift(right)
        return _Value(self.b, self.b.op(op_type, left.name, right.name), max(left.width, right.width),
                      left.per_sample or right.per_sample)

    def unary(self, op_type: str, **attributes) -> "_Value":
        return _Value(self.b, self.b.op(op_type, self.name, **attributes), self.width, self.per_sample)

    # -- arithmetic, as torch computes it --------------------------------------------------------
    def __add__(self, other):
        return self._binary("Add", self, other)

    def __radd__(self, other):
        return self._binary("Add", other, self)

    def __sub__(self, other):
        return self._binary("Sub", self, other)

    def __rsub__(self, other):
        return self._binary("Sub", other, self)

    def __mul__(self, other):
        return self._binary("Mul", self, other)

    def __rmul__(self, other):
        return self._binary("Mul", other, self)

    def __truediv__(self, other):
        return self._binary("Div", self, other)

    def __rtruediv__(self, other):
        # torch: ``other / x`` is ``x.reciprocal() * other``
        inverse = self.unary("Reciprocal")
        return inverse if _is_const(other) and other == 1.0 else self._binary("Mul", inverse, other)

    def __pow__(self, exponent):
        # torch's pow by a scalar: x*x for 2, x*x*x for 3, sqrt for 0.5, else pow
        if exponent == 2:
            return self * self
        if exponent == 3:
            return self * self * self
        if exponent == 0.5:
            return self.unary("Sqrt")
        return self._binary("Pow", self, exponent)

    def __neg__(self):
        return self.unary("Neg")

    def __gt__(self, other):
        return self._binary("Greater", self, other)

    def __lt__(self, other):
        return self._binary("Less", self, other)

    def __ge__(self, other):
        return self._binary("GreaterOrEqual", self, other)

    def __le__(self, other):
        return self._binary("LessOrEqual", self, other)

    def __and__(self, other):
        return self._binary("And", self, other)

    def __or__(self, other):
        return self._binary("Or", self, other)

    def __getitem__(self, key) -> "_Value":
        """Columns ``[:, a:b]`` (how ``BatchVec3`` and ``component`` read a column)."""
        rows, cols = key
        if rows != slice(None) or not isinstance(cols, slice) or cols.step not in (None, 1):
            raise TypeError(f"an ONNX value supports column slices [:, a:b] only, got {key!r}")
        start, stop, _ = cols.indices(self.width)
        b = self.b
        name = b.op("Slice", self.name, _ints(b, [start]), _ints(b, [stop]), _ints(b, [1]))
        return _Value(b, name, stop - start, self.per_sample)


def _scalar(b: _Builder, value: float) -> _Value:
    # (1, 1), not 0-d: onnxruntime 1.32 broadcasts (n, 1) against a 0-d scalar row by row, 30x
    # slower than against (1, 1) (measured: 1.2 ms against 10-40 us for 1e5 rows)
    return _Value(b, b.constant(np.full((1, 1), value, dtype=np.float32)), 1, False)


def _row(b: _Builder, values) -> _Value:
    """A constant (1, width) row (a folded parameter or term, as float32)."""
    array = np.asarray(values.detach().cpu().numpy() if isinstance(values, torch.Tensor) else values,
                       dtype=np.float32).reshape(1, -1)
    return _Value(b, b.constant(array), array.shape[1], False)


def _ints(b: _Builder, values: Sequence[int]) -> str:
    return b.constant(np.asarray(values, dtype=np.int64))


class _OnnxOps(EmittingOps):
    """The ``neuenh.ops`` vocabulary on ``_Value``s (and Python floats, folded by Python), each
    function the ONNX node of what ``TORCH`` computes."""

    name = "onnx"

    def __init__(self, b: _Builder, rows_of: _Value):
        self.b = b
        self._n = b.op("Shape", rows_of.name, start=0, end=1)  # [n], for expanding constant rows

    def unary(self, name: str, x: "_Value") -> "_Value":
        return x.unary(name.capitalize())  # the ONNX operators Sqrt, Exp, ..., Erf, Abs

    def minimum(self, a, b):
        if _is_const(a):
            a, b = b, a
        return self.clamp(a, hi=b) if _is_const(b) else a._binary("Min", a, b)

    def maximum(self, a, b):
        if _is_const(a):
            a, b = b, a
        return self.clamp(a, lo=b) if _is_const(b) else a._binary("Max", a, b)

    def clamp(self, x, lo: float | None = None, hi: float | None = None):
        if _is_const(x):
            return min(max(x, -math.inf if lo is None else lo), math.inf if hi is None else hi)
        bounds = ["" if v is None else self.b.constant(np.array(v, dtype=np.float32)) for v in (lo, hi)]
        return _Value(self.b, self.b.op("Clip", x.name, *bounds), x.width, x.per_sample)

    def where(self, cond, a, b):
        if isinstance(a, BatchVec3):
            other = _row(self.b, b) if isinstance(b, tuple) else b.array
            return BatchVec3(self.where(cond, a.array, other))
        a, b = cond._lift(a), cond._lift(b)
        name = self.b.op("Where", cond.name, a.name, b.name)
        return _Value(self.b, name, max(cond.width, a.width, b.width), cond.per_sample or a.per_sample or b.per_sample)

    def vec3(self, x, y, z) -> BatchVec3:
        like = next(v for v in (x, y, z) if not _is_const(v))
        shape = self.b.op("Shape", like.name)
        cols = [v if not _is_const(v) else _Value(self.b, self.b.op("Expand", _scalar(self.b, v).name, shape), 1,
                                                   like.per_sample) for v in (x, y, z)]
        return BatchVec3(self.concat(cols))

    def dot(self, a: BatchVec3, b: BatchVec3) -> _Value:
        product = a.array * b.array
        return _Value(self.b, self.b.op("ReduceSum", product.name, _ints(self.b, [-1]), keepdims=1), 1,
                      product.per_sample)

    def normalize(self, a: BatchVec3) -> BatchVec3:
        norm = _Value(self.b, self.b.op("ReduceL2", a.array.name, _ints(self.b, [-1]), keepdims=1), 1,
                      a.array.per_sample)
        return BatchVec3(a.array / norm)

    @staticmethod
    def as_vec3(v) -> BatchVec3:
        return v if isinstance(v, BatchVec3) else BatchVec3(v)

    @staticmethod
    def component(p, i: int):
        return p[i] if isinstance(p, (tuple, list)) else p[:, i : i + 1]

    # -- beyond the vocabulary: what the graph walks need ----------------------------------------
    def concat(self, values: Sequence[_Value]) -> _Value:
        name = self.b.op("Concat", *(v.name for v in values), axis=-1)
        return _Value(self.b, name, sum(v.width for v in values), any(v.per_sample for v in values))

    def rows(self, value, width: int) -> _Value:
        """``value`` (a Python float, a row or a per-sample value) as (n, width), like torch's
        ``expand(n, width)``."""
        value = _scalar(self.b, value) if _is_const(value) else value
        if value.per_sample and value.width == width:
            return value
        shape = self.b.op("Concat", self._n, _ints(self.b, [width]), axis=0)
        return _Value(self.b, self.b.op("Expand", value.name, shape), width, True)

    def mlp(self, layers, negative_slope: float, x: _Value) -> _Value:
        """``layers``: (weight (out, in), bias (out,)) pairs, LeakyReLU between them, as ``addmm``."""
        last = len(layers) - 1
        for i, (weight, bias) in enumerate(layers):
            weight, bias = (t.detach().to(torch.float32).cpu().numpy() for t in (weight, bias))
            name = self.b.op("Gemm", x.name, self.b.constant(weight), self.b.constant(bias), transB=1)
            x = _Value(self.b, name, weight.shape[0], True)
            if i < last:
                x = x.unary("LeakyRelu", alpha=float(negative_slope))
        return x

    def finish(self, out: _Value, above: _Value) -> str:
        """``where(above, out.expand(n, 3), 0).clamp_min(0)`` into the graph output ``f_r``."""
        out = self.rows(out, 3)
        masked = self.where(above, out, 0.0)
        return self.b.op("Clip", masked.name, self.b.constant(np.array(0.0, dtype=np.float32)), output="f_r")


# -- the two graphs -----------------------------------------------------------------------------
def material_graph(specialized: SpecializedBRDF, name: str | None = None) -> bytes:
    """The ONNX model (serialized) of one specialized material: ``f_r = brdf(wi, wo)``, its float32
    kernel (``specialized.folded``) op for op. ``name``: the material's name, for the metadata."""
    b = _Builder()
    wi, wo = _Value(b, "wi", 3, True), _Value(b, "wo", 3, True)
    xp = _OnnxOps(b, wi)
    k = specialized.folded.to(torch.float32)
    if k.rotation is None:
        wi_s, wo_s = wi, wo
    else:
        rotation_t = b.constant(k.rotation.t().numpy())
        wi_s, wo_s = (_Value(b, b.op("MatMul", w.name, rotation_t), 3, True) for w in (wi, wo))
    params = {key: v if isinstance(v, float) else _row(b, v) for key, v in k.params.items()}
    s = shade(xp, BatchVec3(wi), BatchVec3(wo), BatchVec3(wi_s), BatchVec3(wo_s), params)
    directions = xp.concat([s.wi.array, s.wo.array]) if k.modules else None

    def formula(term: Term) -> _Value:
        value = term.formula(s)
        return _row(b, [float(value)] * term.width) if _is_const(value) else value

    def module(expr, folded: FoldedModule, operands) -> _Value:
        if operands is None:  # a term's module reads the shading-frame directions
            return xp.mlp(folded.layers, folded.negative_slope, directions)
        left, right = operands
        x = xp.concat([xp.rows(left, expr.left.width), xp.rows(right, expr.right.width)])
        return xp.mlp(folded.layers, folded.negative_slope, x)

    value = walk(specialized.expression, k, constant=lambda expr, v: _row(b, v), formula=formula, module=module)
    output = xp.finish(value, s.above)
    inputs = {"wi": ([BATCH, 3], "incident direction, local frame (z = geometric normal), unit"),
              "wo": ([BATCH, 3], "outgoing direction, local frame, unit")}
    what = f"material {name!r} of " if name is not None else "one material of "
    doc = (f"f_r(wi, wo) of {what}{specialized.model_name} in state {specialized.state} "
           f"({specialized.formula}), specialized: f_r without the cosine factor, 0 below either horizon, >= 0.")
    metadata = {"material": name} if name is not None else {}
    return _serialize(b, output, inputs, doc, {**metadata, **_provenance(specialized.model_name, specialized.state,
                                                                          specialized.formula)})


def generic_graph(model: BRDFModel) -> bytes:
    """The ONNX model (serialized) of ``model`` for any materials: inputs ``wi``, ``wo`` (n, 3), then
    each parameter of ``model.param_names`` (n or 1, width) and ``latent`` (n or 1, latent_dim)
    when a module replaces a term; output ``f_r`` (n, 3) = ``model.evaluate`` (float32)."""
    b = _Builder()
    wi, wo = _Value(b, "wi", 3, True), _Value(b, "wo", 3, True)
    xp = _OnnxOps(b, wi)
    inputs = {"wi": ([BATCH, 3], "incident direction, local frame (z = geometric normal), unit"),
              "wo": ([BATCH, 3], "outgoing direction, local frame, unit")}
    values = {}
    for spec in model.specs:
        values[spec.name] = xp.rows(_Value(b, spec.name, spec.width, False), spec.width)
        scale = ", log scale" if spec.scale == "log" else ""
        inputs[spec.name] = ([PARAM_ROWS, spec.width],
                             f"{spec.doc or spec.name}: physical value in [{spec.low:g}, {spec.high:g}]{scale}, "
                             f"one row per sample or one row for all")
    latent = None
    reads_latent = model.uses_latent
    if reads_latent and model.latent_dim:
        latent = xp.rows(_Value(b, LATENT_NAME, model.latent_dim, False), model.latent_dim)
        inputs[LATENT_NAME] = ([PARAM_ROWS, model.latent_dim], "the material's latent code (neural parameters)")
    shading = make_shading(BatchVec3(wi), BatchVec3(wo), values, xp)

    # BRDFModel._neural_term_outputs: one input per group (modules that read directions or not)
    neural: dict[str, _Value] = {}
    if reads_latent:
        base = [xp.concat([spec.to_unit(values[spec.name], xp) for spec in model.module_specs])]
        if model.latent_dim:
            base.append(latent)
        groups: dict[bool, list[str]] = {}
        for expr, digit in zip(model.graph.positions, model.digits):
            if model.is_neural(digit) and isinstance(expr, Term):
                groups.setdefault(expr.reads_directions, []).append(expr.name)
        for reads_directions, names in groups.items():
            x = xp.concat(base + ([shading.wi.array, shading.wo.array] if reads_directions else []))
            for position in names:
                module = model.neural[position]
                neural[position] = xp.mlp([(l.weight, l.bias) for l in module.layers], module.negative_slope, x)

    def module(op, left: _Value, right: _Value) -> _Value:
        layers = model.neural[op.name]
        operands = xp.concat([xp.rows(left, op.left.width), xp.rows(right, op.right.width)])
        return xp.mlp([(l.weight, l.bias) for l in layers.layers], layers.negative_slope, operands)

    value = model.combine(model.digits, lambda expr, digit: neural[expr.name] if model.is_neural(digit)
                          else expr.formula(shading), module)
    output = xp.finish(value, shading.above)
    shapes = ", ".join(f"{k} ({', '.join(map(str, v[0]))})" for k, v in inputs.items())
    doc = (f"f_r(wi, wo, parameters) of {model.name} in state {model.state} ({model.describe()}) for any "
           f"materials: f_r without the cosine factor, 0 below either horizon, >= 0. Inputs: {shapes}; "
           f"parameters are physical values inside their ranges (not checked).")
    return _serialize(b, output, inputs, doc, _provenance(model.name, model.state, model.describe()))


def nbrdf_graph(net, name: str | None = None) -> bytes:
    """The ONNX model (serialized) of one NBRDF network (``neuenh.export.nbrdf``, a ``NBRDFNetwork``):
    inputs ``wi``, ``wo``, output ``f_r``, as a material's graph."""
    from .nbrdf import above, brdf, folded_network

    b = _Builder()
    wi, wo = _Value(b, "wi", 3, True), _Value(b, "wo", 3, True)
    xp = _OnnxOps(b, wi)
    network = folded_network(net)
    value = brdf(xp, BatchVec3(wi), BatchVec3(wo),
                 lambda inputs: xp.mlp(network.layers, network.negative_slope, xp.concat(inputs)))
    output = xp.finish(value, above(BatchVec3(wi), BatchVec3(wo)))
    inputs = {"wi": ([BATCH, 3], "incident direction, local frame (z = normal), unit"),
              "wo": ([BATCH, 3], "outgoing direction, local frame, unit")}
    formula = "exp(W3 relu(W2 relu(W1 x + b1) + b2) + b3) - 1"
    what = f"material {name!r}" if name is not None else "one material"
    doc = (f"f_r(wi, wo) of {what}: its per-material NBRDF network (Sztrajman et al. 2021), f_r = {formula}; "
           "without the cosine factor, 0 below either horizon, >= 0.")
    metadata = {"material": name} if name is not None else {}
    return _serialize(b, output, inputs, doc, {**metadata, **_provenance("nbrdf", "", formula)})


def _provenance(model_name: str, state: str, formula: str) -> dict[str, str]:
    return {"model": model_name, "state": state, "formula": formula, "neuenh_version": __version__}


def _serialize(b: _Builder, output: str, inputs: Mapping[str, tuple[list, str]], doc: str,
               metadata: Mapping[str, str]) -> bytes:
    def info(name: str, dims: list, text: str) -> onnx.ValueInfoProto:
        value = helper.make_tensor_value_info(name, TensorProto.FLOAT, dims)
        value.doc_string = text
        return value

    # Only what the output reads (folded parameters no formula reads, e.g. the shading normal's
    # angles, and helper nodes built in advance are dropped), in build order (a topological order).
    needed, nodes = {output}, []
    for node in reversed(b.nodes):
        if node.output[0] in needed:
            nodes.append(node)
            needed.update(node.input)
    graph = helper.make_graph(
        nodes[::-1], "brdf", [info(k, dims, text) for k, (dims, text) in inputs.items()],
        [info(output, [BATCH, 3], "f_r: BRDF value (RGB), without the cosine factor")],
        initializer=[t for t in b.initializers if t.name in needed], doc_string=doc)
    opset = helper.make_opsetid("", OPSET)
    model = helper.make_model(graph, opset_imports=[opset], producer_name="neuenh", producer_version=__version__,
                              ir_version=helper.find_min_ir_version_for([opset]), doc_string=doc)
    shapes = {k: dims for k, (dims, _) in inputs.items()} | {"f_r": [BATCH, 3]}
    helper.set_model_props(model, {**metadata, "inputs": json.dumps(shapes)})
    return model.SerializeToString()


# -- the exporter entry point -------------------------------------------------------------------
def file_stem(name: str) -> str:
    """A material or model name as a file name stem: runs of characters other than letters,
    digits, ``.``, ``_`` and ``-`` become ``_``; leading and trailing ``.``, ``_``, ``-`` go."""
    stem = re.sub(r"[^0-9A-Za-z._-]+", "_", str(name)).strip("._-")
    if not stem:
        raise ValueError(f"name {name!r} leaves nothing usable as a file name")
    return stem


def write(model: BRDFModel, materials: Mapping[str, MaterialParams], out_dir: Path) -> list[Path]:
    """``NAME.onnx`` (``material_graph``) per material and ``MODEL-generic.onnx`` (``generic_graph``)
    once, into ``out_dir``; returns their paths, materials first in the given order.

    Every graph is built before anything is written: a bad material (its parameters, or a name
    whose file name another name already takes, case-insensitively) raises a ValueError and writes
    nothing. Each file is written to a temporary file in ``out_dir`` and renamed into place, so a
    reader never sees half a file."""
    generic = f"{file_stem(model.name)}{GENERIC_SUFFIX}.onnx"

    def graph(name: str, params: MaterialParams) -> bytes:
        try:
            specialized = model.specialize(params)
        except ValueError as error:
            raise ValueError(f"material {name!r}: {error}") from None
        return material_graph(specialized, name=name)

    return _write_graphs(materials, graph, Path(out_dir), {generic: (f"the generic model's {generic}",
                                                                     lambda: generic_graph(model))})


def write_nbrdf(networks: Mapping[str, object], out_dir: Path) -> list[Path]:
    """``NAME.onnx`` (``nbrdf_graph``) per NBRDF network, as ``write`` writes a model's materials."""
    return _write_graphs(networks, lambda name, net: nbrdf_graph(net, name=name), Path(out_dir), {})


def _write_graphs(materials: Mapping, graph, out_dir: Path, extra: Mapping) -> list[Path]:
    """``graph(name, material)`` as ``NAME.onnx`` per material, then ``extra`` (file -> (what it is,
    its graph's maker)): every graph built before anything is written, no two file names alike
    (case-insensitively), each file written atomically."""
    taken = {file.casefold(): what for file, (what, _) in extra.items()}
    files: list[tuple[Path, bytes]] = []
    for name, material in materials.items():
        file = f"{file_stem(name)}.onnx"
        if file.casefold() in taken:
            raise ValueError(f"material {name!r} would be written to {file}, as {taken[file.casefold()]}; rename one")
        taken[file.casefold()] = f"material {name!r}"
        files.append((out_dir / file, graph(name, material)))
    files += [(out_dir / file, make()) for file, (_, make) in extra.items()]
    out_dir.mkdir(parents=True, exist_ok=True)
    for path, blob in files:
        atomic_write(path, blob)
    return [path for path, _ in files]

