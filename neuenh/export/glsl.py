"""GLSL export: a fitted material as ``vec3 neuenh_brdf(vec3 wi, vec3 wo)``.

The exported function is the specialized evaluator (``neuenh.specialize``) written out in GLSL 4.50:
f_r without the cosine factor, ``wi`` and ``wo`` unit vectors in the local shading frame (z the
geometric normal, x the tangent before ``t_theta``), exactly zero below either horizon. The
material's parameters, its shading frame and the neural modules' weights (with the per-material
inputs folded into their first-layer biases) are constants of the source. There is no ``#version``
line and no ``main``: include the file in any GLSL 4.50 core shader (docs/EXPORT.md).

How the source is made: the analytical terms are the same backend-neutral formulas the torch model
runs (``neuenh.ops``), evaluated once on a *tracer* backend whose values are GLSL expressions; every
operation appends one single-assignment statement (``float t12 = t7 * t9;``), and Python folds the
arithmetic among constants as it does for the torch evaluator. So the GLSL cannot drift from the
model: there is no second hand-written copy of a formula. Each neural module becomes a function of
``mat4 * vec4`` products over constant 4x4 blocks of its weights (``_module_function``).

Names: every symbol of a file is prefixed ``neuenh_<material>_``, and ``neuenh_brdf`` forwards to
``neuenh_<material>_brdf`` unless ``NEUENH_NO_DEFAULT_BRDF`` is defined, so several materials can
be included in one shader (a scene) and called by their own names.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any, Mapping

import torch

from ..ops import EmittingOps, _is_const
from ..shading import make_shading, shade
from ..materials import LATENT_NAME, MaterialParams
from ..specialize import FoldedModule, SpecializedBRDF, _fold, walk
from ..files import atomic_write
from . import file_names

VERSION = 450  # the GLSL version the source is written for (core profile)


# -- the tracer: GLSL expressions as the values of the ops vocabulary -------------------------------
def literal(x: float) -> str:
    """A GLSL float literal for ``x`` (shortest round-trip repr; GLSL rounds it to float32)."""
    x = float(x)
    if math.isinf(x):
        return "uintBitsToFloat(0x7F800000u)" if x > 0 else "uintBitsToFloat(0xFF800000u)"
    if math.isnan(x):
        raise ValueError("a NaN constant cannot be exported")
    text = repr(x)
    if not any(c in text for c in ".e"):
        text += ".0"
    return f"({text})" if math.copysign(1.0, x) < 0 else text


class Code:
    """Straight-line GLSL: single-assignment statements, each naming one intermediate value."""

    def __init__(self, prefix: str):
        self.prefix, self.lines, self.count = prefix, [], 0

    def let(self, glsl_type: str, expr: str) -> "Expr":
        name = f"t{self.count}"
        self.count += 1
        self.lines.append(f"    {glsl_type} {name} = {expr};")
        return Expr(self, glsl_type, name)


class Expr:
    """A per-sample GLSL value: a name (or literal) and its type, ``float``, ``vec3`` or ``bool``.
    A ``vec3`` serves both as a direction (``.x``, ``.y``, ``.z``) and as an RGB value."""

    __slots__ = ("code", "type", "text")
    __array_ufunc__ = None

    def __init__(self, code: Code, glsl_type: str, text: str):
        self.code, self.type, self.text = code, glsl_type, text

    # components of a direction
    @property
    def x(self) -> "Expr":
        return Expr(self.code, "float", f"{self.text}.x")

    @property
    def y(self) -> "Expr":
        return Expr(self.code, "float", f"{self.text}.y")

    @property
    def z(self) -> "Expr":
        return Expr(self.code, "float", f"{self.text}.z")

    def _binary(self, op: str, other, reflected: bool = False) -> "Expr":
        a, b = (other, self) if reflected else (self, other)
        kind = "vec3" if "vec3" in (_type(a), _type(b)) else "float"
        if op in (">", "<", ">=", "<=", "&&", "||"):
            kind = "bool"
        return self.code.let(kind, f"{_text(a)} {op} {_text(b)}")

    def __add__(self, o): return self._binary("+", o)  # noqa: E704
    def __radd__(self, o): return self._binary("+", o, True)  # noqa: E704
    def __sub__(self, o): return self._binary("-", o)  # noqa: E704
    def __rsub__(self, o): return self._binary("-", o, True)  # noqa: E704
    def __mul__(self, o): return self._binary("*", o)  # noqa: E704
    def __rmul__(self, o): return self._binary("*", o, True)  # noqa: E704
    def __truediv__(self, o): return self._binary("/", o)  # noqa: E704
    def __rtruediv__(self, o): return self._binary("/", o, True)  # noqa: E704
    def __gt__(self, o): return self._binary(">", o)  # noqa: E704
    def __lt__(self, o): return self._binary("<", o)  # noqa: E704
    def __ge__(self, o): return self._binary(">=", o)  # noqa: E704
    def __le__(self, o): return self._binary("<=", o)  # noqa: E704
    def __and__(self, o): return self._binary("&&", o)  # noqa: E704
    def __or__(self, o): return self._binary("||", o)  # noqa: E704

    def __neg__(self) -> "Expr":
        return self.code.let(self.type, f"-{self.text}")

    def __pow__(self, exponent) -> "Expr":
        """Integer powers as products (exact, and defined for negative bases, unlike ``pow``)."""
        if float(exponent).is_integer() and 1 <= exponent <= 8:
            result = self
            for _ in range(int(exponent) - 1):
                result = result * self
            return result
        return self.code.let(self.type, f"pow({self.text}, {literal(exponent)})")


def _type(v) -> str:
    return v.type if isinstance(v, Expr) else "float"


def _text(v) -> str:
    return v.text if isinstance(v, Expr) else literal(v)


class GlslOps(EmittingOps):
    """The ``neuenh.ops`` vocabulary on ``Expr`` values (and Python floats, folded by Python)."""

    name = "glsl"

    def __init__(self, code: Code):
        self.code = code

    def _call(self, fn: str, *args, kind: str | None = None) -> Expr:
        kind = kind or ("vec3" if any(_type(a) == "vec3" for a in args) else "float")
        return self.code.let(kind, f"{fn}({', '.join(_text(a) for a in args)})")

    def unary(self, name: str, x) -> Expr:
        if name == "erf":
            raise NotImplementedError("erf has no GLSL built-in; no exported formula uses it yet")
        return self._call(name, x)  # GLSL's built-ins share the vocabulary's names

    def minimum(self, a, b):
        return min(a, b) if _is_const(a) and _is_const(b) else self._call("min", a, b)

    def maximum(self, a, b):
        return max(a, b) if _is_const(a) and _is_const(b) else self._call("max", a, b)

    def clamp(self, x, lo: float | None = None, hi: float | None = None):
        if _is_const(x):
            return min(max(x, -math.inf if lo is None else lo), math.inf if hi is None else hi)
        if lo is not None and hi is not None:
            return self._call("clamp", x, lo, hi)
        return self._call("max", x, lo) if lo is not None else self._call("min", x, hi)

    def where(self, cond: Expr, a, b):
        b = self.vec3(*b) if isinstance(b, tuple) else b
        kind = "vec3" if "vec3" in (_type(a), _type(b)) else "float"
        widen = (lambda v: f"vec3({_text(v)})") if kind == "vec3" else _text  # noqa: E731
        a_text = _text(a) if _type(a) == kind else widen(a)
        b_text = _text(b) if _type(b) == kind else widen(b)
        return self.code.let(kind, f"{cond.text} ? {a_text} : {b_text}")

    def vec3(self, x, y, z) -> Expr:
        return Expr(self.code, "vec3", f"vec3({_text(x)}, {_text(y)}, {_text(z)})") if all(
            _is_const(v) for v in (x, y, z)) else self.code.let("vec3", f"vec3({_text(x)}, {_text(y)}, {_text(z)})")

    def dot(self, a: Expr, b: Expr) -> Expr:
        return self._call("dot", a, b, kind="float")

    def normalize(self, a: Expr) -> Expr:
        return self._call("normalize", a)

    def as_vec3(self, v):
        return v

    def component(self, p, i: int):
        return p[i] if isinstance(p, (tuple, list)) else Expr(self.code, "float", f"{p.text}[{i}]")


# -- one material ----------------------------------------------------------------------------------
def _prefix(name: str) -> str:
    """The symbols' prefix of material ``name``, an identifier part (``neuenh.export.identifier``)."""
    if not re.fullmatch(r"[A-Za-z0-9_]+", name) or "__" in name:
        raise ValueError(f"{name!r}: a GLSL material name is letters, digits and single underscores "
                         "(neuenh.export.identifier)")
    return f"neuenh_{name}_"


def material_source(brdf: SpecializedBRDF, name: str) -> str:
    """The GLSL of one specialized material (see the module docstring); ``name`` must be an
    identifier part (``neuenh.export.identifier``)."""
    prefix = _prefix(name)
    folded = brdf.folded.to(torch.float64)  # constants at full precision; GLSL rounds each once
    code = Code(prefix)
    xp = GlslOps(code)
    wi, wo = Expr(code, "vec3", "wi"), Expr(code, "vec3", "wo")
    if folded.rotation is None:
        wi_s, wo_s = wi, wo
    else:
        rows = ", ".join(literal(v) for v in folded.rotation.t().reshape(-1).tolist())  # column-major
        frame = f"{prefix}frame"
        wi_s, wo_s = (code.let("vec3", f"{frame} * {w.text}") for w in (wi, wo))
    params = {k: _constant_value(code, v) for k, v in folded.params.items()}
    s = shade(xp, wi, wo, wi_s, wo_s, params)

    functions = [_module_function(prefix, module) for module in folded.modules.values()]

    def module(expr, folded_module: FoldedModule, operands):
        if operands is None:  # a term's module reads the shading-frame directions
            return _call_module(code, prefix, folded_module, [s.wi, s.wo], (3, 3))
        return _call_module(code, prefix, folded_module, list(operands), (expr.left.width, expr.right.width))

    value = walk(brdf.expression, folded, constant=lambda expr, v: _constant_value(code, v),
                 formula=lambda term: term.formula(s), module=module)
    value = xp.where(s.above, value, (0.0, 0.0, 0.0))
    if _type(value) != "vec3":
        value = code.let("vec3", f"vec3({_text(value)})")
    header = [
        f"// neuenh export: {brdf.model_name} material '{name}', state {brdf.state}",
        f"// f_r = {brdf.formula}",
        "// f_r(wi, wo) without the cosine factor; wi, wo: unit vectors in the local shading frame",
        "// (z the geometric normal, x the tangent before t_theta); zero below either horizon.",
        f"// GLSL {VERSION} core; no #version line and no main(): include it in your shader.",
    ]
    if folded.rotation is not None:
        header.append(f"const mat3 {frame} = mat3({rows});  // rows: tangent, bitangent, normal")
    return _source(header, functions, prefix, code, value)


def nbrdf_source(net, name: str) -> str:
    """The GLSL of one NBRDF network (``neuenh.export.nbrdf``, a ``NBRDFNetwork``) as material ``name``:
    the same function and names as a model's material."""
    from .nbrdf import above, brdf, folded_network

    prefix, network = _prefix(name), folded_network(net)
    code = Code(prefix)
    xp = GlslOps(code)
    wi, wo = Expr(code, "vec3", "wi"), Expr(code, "vec3", "wo")
    value = brdf(xp, wi, wo, lambda inputs: _call_module(code, prefix, network, inputs, (1,) * len(inputs)))
    header = [
        f"// neuenh export: the per-material NBRDF network (Sztrajman et al. 2021) of material '{name}'",
        "// f_r = exp(W3 relu(W2 relu(W1 x + b1) + b2) + b3) - 1, x of the Rusinkiewicz angles (neuenh.export.nbrdf)",
        "// f_r(wi, wo) without the cosine factor; wi, wo: unit vectors in the local frame (z the normal);",
        "// zero below either horizon.",
        f"// GLSL {VERSION} core; no #version line and no main(): include it in your shader.",
    ]
    value = xp.where(above(wi, wo), value, (0.0, 0.0, 0.0))
    return _source(header, [_module_function(prefix, network)], prefix, code, value)


def _source(header: list[str], functions: list[str], prefix: str, code: Code, value) -> str:
    """A material's file: ``header`` comments, the module ``functions``, ``<prefix>brdf`` returning
    ``value`` clamped at 0, and ``neuenh_brdf`` forwarding to it."""
    body = [f"vec3 {prefix}brdf(vec3 wi, vec3 wo) {{", *code.lines,
            f"    return max({value.text}, vec3(0.0));", "}"]
    default = ["#ifndef NEUENH_NO_DEFAULT_BRDF",
               f"vec3 neuenh_brdf(vec3 wi, vec3 wo) {{ return {prefix}brdf(wi, wo); }}", "#endif"]
    return "\n".join(header + [""] + [f for fn in functions for f in (fn, "")] + body + [""] + default) + "\n"


def _constant_value(code: Code, value: Any):
    """A folded parameter or term: a float, a ``vec3`` literal, or a tuple for other widths."""
    if isinstance(value, float):
        return value
    flat = [float(v) for v in torch.as_tensor(value).reshape(-1).tolist()]
    if len(flat) == 1:
        return flat[0]
    if len(flat) == 3:
        return Expr(code, "vec3", f"vec3({', '.join(literal(v) for v in flat)})")
    return tuple(flat)


def _vec4(values) -> str:
    return f"vec4({', '.join(literal(v) for v in values)})"


def _module_function(prefix: str, module: FoldedModule) -> str:
    """``float|vec3 <prefix>m_<position>(vec4 x0[K])``: the folded MLP as straight-line ``mat4 *
    vec4`` products over constant 4x4 blocks (zero-padded to multiples of 4). Constant indices
    only: a dynamically indexed constant array is copied per invocation by some compilers (Mesa's
    llvmpipe took ~40 s for 8,192 evaluations of a 64-wide MLP written with loops)."""
    fn = f"{prefix}m_{_ident(module.position)}"
    blocks = lambda n: -(-n // 4)  # noqa: E731  (vec4 blocks holding n values)
    consts, body = [], []
    for i, (weight, bias) in enumerate(module.layers):
        n_out, n_in = weight.shape
        padded = torch.zeros(blocks(n_out) * 4, blocks(n_in) * 4, dtype=torch.float64)
        padded[:n_out, :n_in] = weight
        bias = torch.cat([bias, torch.zeros(blocks(n_out) * 4 - n_out, dtype=torch.float64)])
        last = i == len(module.layers) - 1
        for o in range(blocks(n_out)):
            terms = [f"{fn}_b{i}_{o}"]
            consts.append(f"const vec4 {fn}_b{i}_{o} = {_vec4(bias[4 * o : 4 * o + 4].tolist())};")
            for k in range(blocks(n_in)):
                block = padded[4 * o : 4 * o + 4, 4 * k : 4 * k + 4]
                if not block.any():
                    continue
                # mat4(...) takes columns: the block's transpose, row by row
                consts.append(f"const mat4 {fn}_w{i}_{o}_{k} = mat4({', '.join(literal(v) for v in block.t().reshape(-1).tolist())});")
                source = f"x0[{k}]" if i == 0 else f"x{i}_{k}"
                terms.append(f"{fn}_w{i}_{o}_{k} * {source}")
            body.append(f"    vec4 x{i + 1}_{o} = {' + '.join(terms)};")
            if not last:  # LeakyReLU: max(x, slope x) for a slope below 1
                body.append(f"    x{i + 1}_{o} = max(x{i + 1}_{o}, {literal(module.negative_slope)} * x{i + 1}_{o});")
    n, out = len(module.layers), module.layers[-1][0].shape[0]
    result = f"x{n}_0.x" if out == 1 else f"x{n}_0.xyz"
    width = blocks(module.layers[0][0].shape[1])
    return "\n".join(consts + [f"{'float' if out == 1 else 'vec3'} {fn}(vec4 x0[{width}]) {{", *body,
                                f"    return {result};", "}"])


def _call_module(code: Code, prefix: str, module: FoldedModule, inputs: list, widths: tuple[int, int]) -> Expr:
    """A module called on the concatenation of ``inputs`` (floats or vec3s, of ``widths``), packed
    into zero-padded vec4 blocks."""
    parts = []
    for value, width in zip(inputs, widths):
        if width == 1:
            parts.append(_text(value))
        else:
            text = _text(value) if _type(value) == "vec3" else f"vec3({_text(value)})"
            parts += [f"{text}.{c}" for c in "xyz"]
    parts += ["0.0"] * (-len(parts) % 4)
    k = len(parts) // 4
    array = code.let(f"vec4[{k}]", f"vec4[{k}]({', '.join('vec4(' + ', '.join(parts[4 * i : 4 * i + 4]) + ')' for i in range(k))})")
    out = module.layers[-1][0].shape[0]
    return code.let("float" if out == 1 else "vec3", f"{prefix}m_{_ident(module.position)}({array.text})")


def _ident(position: str) -> str:
    """A position name as an identifier part (``S*D*F`` -> ``S_x_D_x_F``)."""
    return re.sub(r"[^A-Za-z0-9_]", "_", position.replace("*", "_x_").replace("+", "_p_"))


# -- the model for any material ---------------------------------------------------------------------
def parameter_layout(model) -> list[tuple[str, int, int]]:
    """(name, offset, width) of every parameter in the generic function's ``float p[]``: the model's
    parameters in ``model.param_names`` order, then ``latent`` when a module reads it."""
    layout, offset = [], 0
    for spec in model.specs:
        layout.append((spec.name, offset, spec.width))
        offset += spec.width
    if model.uses_latent and model.latent_dim:
        layout.append((LATENT_NAME, offset, model.latent_dim))
    return layout


def model_source(model) -> str:
    """``vec3 neuenh_MODEL_brdf(vec3 wi, vec3 wo, float p[N])``: the model for any material, its
    physical parameter values in ``p`` (``parameter_layout``), and, unless
    ``NEUENH_MODEL_NO_UNIFORM`` is defined, ``neuenh_MODEL_material_brdf(wi, wo)`` reading them from
    the uniform block ``NeuenhMODELParams`` (std140: ``vec4 neuenh_MODEL_params[K]``, component i at
    ``[i / 4][i % 4]``). The frame, the terms and the modules run per call (nothing is folded): the
    specialized per-material files are faster; this one serves materials that change at run time."""
    name = _ident(model.name)
    prefix = f"neuenh_{name}_"
    code = Code(prefix)
    xp = GlslOps(code)
    wi, wo = Expr(code, "vec3", "wi"), Expr(code, "vec3", "wo")
    layout = parameter_layout(model)
    n = layout[-1][1] + layout[-1][2]
    values = {}
    for pname, offset, width in layout:
        if pname == LATENT_NAME:
            continue
        cells = [Expr(code, "float", f"p[{offset + i}]") for i in range(width)]
        values[pname] = cells[0] if width == 1 else (
            code.let("vec3", f"vec3({', '.join(c.text for c in cells)})") if width == 3 else tuple(cells))
    s = make_shading(wi, wo, values, xp)
    # every module reads the model's own parameters as unit values (ParamSpec.to_unit), then the latent
    unit = []
    for spec in model.module_specs:
        offset = next(o for pn, o, _ in layout if pn == spec.name)
        unit += [spec.to_unit(Expr(code, "float", f"p[{offset + i}]"), xp) for i in range(spec.width)]
    latent = [Expr(code, "float", f"p[{o + i}]") for pn, o, w in layout if pn == LATENT_NAME for i in range(w)]
    shared = {k: w.detach() for k, w in model.neural.named_parameters()}
    modules = {position: _fold(position, module, shared, None, True) for position, module in model.neural.items()}
    functions = [_module_function(prefix, m) for m in modules.values()]

    def term(expr, digit):
        if not model.is_neural(digit):
            return expr.formula(s)
        inputs = unit + latent + ([s.wi, s.wo] if expr.reads_directions else [])
        widths = [1] * (len(unit) + len(latent)) + ([3, 3] if expr.reads_directions else [])
        return _call_module(code, prefix, modules[expr.name], inputs, widths)

    def module(op, left, right):
        return _call_module(code, prefix, modules[op.name], [left, right], (op.left.width, op.right.width))

    value = xp.where(s.above, model.combine(model.digits, term, module), (0.0, 0.0, 0.0))
    if _type(value) != "vec3":
        value = code.let("vec3", f"vec3({_text(value)})")
    blocks = -(-n // 4)
    fields = ", ".join(f"{pname} [{offset}" + (f"..{offset + width - 1}]" if width > 1 else "]")
                       for pname, offset, width in layout)
    header = [f"// neuenh export: the generic {model.name} in state {model.state}, for any material",
              f"// f_r = {model.describe()}",
              "// f_r(wi, wo, p) without the cosine factor, local shading frame, zero below either horizon;",
              f"// p: {n} physical parameter values: {fields}."]
    body = [f"vec3 {prefix}brdf(vec3 wi, vec3 wo, float p[{n}]) {{", *code.lines,
            f"    return max({value.text}, vec3(0.0));", "}"]
    uniform = ["#ifndef NEUENH_MODEL_NO_UNIFORM",
               f"layout(std140) uniform Neuenh{name}Params {{ vec4 {prefix}params[{blocks}]; }};",
               f"vec3 {prefix}material_brdf(vec3 wi, vec3 wo) {{",
               f"    float p[{n}];",
               f"    for (int i = 0; i < {n}; ++i) p[i] = {prefix}params[i / 4][i % 4];",
               f"    return {prefix}brdf(wi, wo, p);", "}", "#endif"]
    return "\n".join(header + [""] + [f for fn in functions for f in (fn, "")] + body + [""] + uniform) + "\n"


def pack_parameters(model, params: MaterialParams | Mapping[str, Any]) -> list[float]:
    """One material's parameters (what ``specialize`` takes) as the generic function's ``p``. The
    generic function holds the shared module weights: a material with corrections is refused (its
    own file, ``material_source``, carries them)."""
    record = MaterialParams.of(params)
    if record.corrections:
        raise ValueError(f"this material corrects {len(record.corrections)} module weight tensor(s), which the generic "
                         "function cannot take; export the material's own file (material_source)")
    values = {**model.complete_params(record.values), LATENT_NAME: record.latent}
    out = []
    for pname, _, width in parameter_layout(model):
        if values.get(pname) is None:
            raise ValueError(f"parameter {pname!r} is missing")
        numbers = [float(v) for v in torch.as_tensor(values[pname]).reshape(-1).tolist()]
        if len(numbers) != width:
            raise ValueError(f"parameter {pname!r} has width {width}, got {len(numbers)} values")
        out += numbers
    return out


# -- files ---------------------------------------------------------------------------------------------
def write(model, materials: Mapping[str, MaterialParams], out_dir: Path) -> list[Path]:
    """``NAME.glsl`` per material (``NAME``: ``neuenh.export.identifier``) and ``MODEL-generic.glsl``
    (``model_source``), written atomically."""
    names = file_names(materials, ".glsl")
    generic = f"{_ident(model.name)}-generic.glsl"  # material files are identifiers: no '-', no clash
    out_dir.mkdir(parents=True, exist_ok=True)
    written = [atomic_write(out_dir / f"{name}.glsl", material_source(model.specialize(materials[material]), name))
               for name, material in names.items()]
    return written + [atomic_write(out_dir / generic, model_source(model))]


def write_nbrdf(networks: Mapping[str, Any], out_dir: Path) -> list[Path]:
    """``NAME.glsl`` (``nbrdf_source``) per NBRDF network, written atomically."""
    names = file_names(networks, ".glsl")
    sources = {name: nbrdf_source(networks[material], name) for name, material in names.items()}
    out_dir.mkdir(parents=True, exist_ok=True)
    return [atomic_write(out_dir / f"{name}.glsl", source) for name, source in sources.items()]
