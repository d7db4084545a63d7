"""The math vocabulary BRDF formulas are written in, so that one formula runs on several backends.

Terms (``neuenh.models``) and the shading geometry (``neuenh.shading``) never call torch directly:
they combine per-sample values with arithmetic operators and the functions of the namespace
handed to them as ``s.xp``. The same formula then runs

* in torch (``TORCH``): training, fitting, evaluation and the specialized evaluator;
* in numpy (``NUMPY``): a second backend that tests run every model on, which keeps the formulas
  honest (a formula that reaches for torch fails there);
* in the exporters (``neuenh.export``, on ``EmittingOps``): Dr.Jit arrays in the Mitsuba plugin,
  a GLSL code tracer, ONNX graph nodes; and Dr.Jit arrays in the fit's compiled kernel
  (``DrJitArrayOps``, ``neuenh.fit.jit``).

Values. A per-sample scalar is an ``(n, 1)`` array; an RGB value is ``(n, 3)`` and scalars
broadcast against it. A Python ``float`` is a constant: arithmetic between constants is done by
Python itself, so a formula evaluated with one material's parameters as floats folds everything
that does not depend on the directions (``TORCH`` and ``NUMPY`` accept floats wherever they accept
arrays). A direction is a ``Vec3`` of the backend: ``.x``, ``.y``, ``.z`` scalars, ``+``, ``-``,
``*`` and ``/`` by a scalar, and ``dot``, ``normalize``, ``where`` from the namespace.

The vocabulary (every backend implements exactly these):

    sqrt exp log sin cos tan erf abs     element-wise
    minimum(a, b)  maximum(a, b)         element-wise, floats allowed on either side
    clamp(x, lo=None, hi=None)           lo/hi are Python floats
    where(cond, a, b)                    scalars or Vec3s (``b`` may be a constant 3-tuple);
                                         ``cond`` is a per-sample bool
    vec3(x, y, z)  dot(a, b)  normalize(a)
    as_vec3(v)                           the backend's Vec3 of an (n, 3) array (or v itself)
    component(p, i)                      component i of a multi-width parameter (e.g. ``normal``)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch


class BatchVec3:
    """A batch of 3-vectors held as one ``(n, 3)`` array (torch or numpy), so vector ops stay
    single array ops."""

    __slots__ = ("array",)
    __array_ufunc__ = None  # numpy defers ``array * vec`` to __rmul__ instead of broadcasting over it

    def __init__(self, array):
        self.array = array

    @property
    def x(self):
        return self.array[:, 0:1]

    @property
    def y(self):
        return self.array[:, 1:2]

    @property
    def z(self):
        return self.array[:, 2:3]

    def __add__(self, other: "BatchVec3") -> "BatchVec3":
        return BatchVec3(self.array + other.array)

    def __sub__(self, other: "BatchVec3") -> "BatchVec3":
        return BatchVec3(self.array - other.array)

    def __mul__(self, scalar) -> "BatchVec3":
        return BatchVec3(self.array * scalar)

    __rmul__ = __mul__

    def __truediv__(self, scalar) -> "BatchVec3":
        return BatchVec3(self.array / scalar)


def _is_const(x: Any) -> bool:
    return isinstance(x, (int, float))


# The vocabulary's functions of one argument, as Python computes them on a constant.
FOLDED_UNARY = {"sqrt": math.sqrt, "exp": math.exp, "log": math.log, "sin": math.sin, "cos": math.cos,
                "tan": math.tan, "erf": math.erf, "abs": abs}


class EmittingOps:
    """Base of the backends that emit code or graph nodes (``neuenh.export``): each function of one
    argument is computed by Python on a constant (folded) and otherwise emitted by ``unary(name, x)``,
    the backend's own spelling of ``name`` (a key of ``FOLDED_UNARY``)."""

    def unary(self, name: str, x):
        raise NotImplementedError

    def _fold_or_emit(self, name: str, x):
        return FOLDED_UNARY[name](x) if _is_const(x) else self.unary(name, x)

    def sqrt(self, x):
        return self._fold_or_emit("sqrt", x)

    def exp(self, x):
        return self._fold_or_emit("exp", x)

    def log(self, x):
        return self._fold_or_emit("log", x)

    def sin(self, x):
        return self._fold_or_emit("sin", x)

    def cos(self, x):
        return self._fold_or_emit("cos", x)

    def tan(self, x):
        return self._fold_or_emit("tan", x)

    def erf(self, x):
        return self._fold_or_emit("erf", x)

    def abs(self, x):
        return self._fold_or_emit("abs", x)


class DrJitArrayOps(EmittingOps):
    """The vocabulary on Dr.Jit arrays: per-sample scalars are the backend's ``Float``, directions and
    RGB values its ``vec3_type`` (``drjit.llvm.ad.Array3f`` unless given: the fit's compiled kernel,
    ``neuenh.fit.jit``; Mitsuba's ``Vector3f`` in its plugin); Python floats fold. Imports ``drjit``
    when made (an optional dependency)."""

    name = "drjit"

    def __init__(self, vec3_type=None):
        import drjit as dr

        if vec3_type is None:
            from drjit.llvm.ad import Array3f as vec3_type
        self.dr, self.vec3_type = dr, vec3_type

    def unary(self, name: str, x):
        return getattr(self.dr, name)(x)  # Dr.Jit's functions share the vocabulary's names

    def minimum(self, a, b):
        return min(a, b) if _is_const(a) and _is_const(b) else self.dr.minimum(a, b)

    def maximum(self, a, b):
        return max(a, b) if _is_const(a) and _is_const(b) else self.dr.maximum(a, b)

    def clamp(self, x, lo: float | None = None, hi: float | None = None):
        if _is_const(x):
            return min(max(x, -math.inf if lo is None else lo), math.inf if hi is None else hi)
        if lo is not None:
            x = self.dr.maximum(x, lo)
        return x if hi is None else self.dr.minimum(x, hi)

    def where(self, cond, a, b):
        if isinstance(b, tuple):
            b = self.vec3_type(*b)
        return self.dr.select(cond, a, b)

    def vec3(self, x, y, z):
        return self.vec3_type(x, y, z)

    def dot(self, a, b):
        return self.dr.dot(a, b)

    def normalize(self, a):
        return self.dr.normalize(a)

    @staticmethod
    def as_vec3(v):
        return v

    @staticmethod
    def component(p, i: int):
        return p[i]


class _TorchOps:
    """The vocabulary on torch tensors (and Python floats, folded by Python)."""

    name = "torch"

    @staticmethod
    def _unary(const_fn, tensor_fn):
        return lambda x: const_fn(x) if _is_const(x) else tensor_fn(x)

    sqrt = staticmethod(_unary(math.sqrt, torch.sqrt))
    exp = staticmethod(_unary(math.exp, torch.exp))
    log = staticmethod(_unary(math.log, torch.log))
    sin = staticmethod(_unary(math.sin, torch.sin))
    cos = staticmethod(_unary(math.cos, torch.cos))
    tan = staticmethod(_unary(math.tan, torch.tan))
    erf = staticmethod(_unary(math.erf, torch.erf))
    abs = staticmethod(_unary(abs, torch.abs))

    @staticmethod
    def minimum(a, b):
        if _is_const(a):
            a, b = b, a
        # a constant bound is a clamp (folded by Python when both are constants)
        return _TorchOps.clamp(a, hi=b) if _is_const(b) else torch.minimum(a, b)

    @staticmethod
    def maximum(a, b):
        if _is_const(a):
            a, b = b, a
        return _TorchOps.clamp(a, lo=b) if _is_const(b) else torch.maximum(a, b)

    @staticmethod
    def clamp(x, lo: float | None = None, hi: float | None = None):
        if _is_const(x):
            return min(max(x, -math.inf if lo is None else lo), math.inf if hi is None else hi)
        return torch.clamp(x, lo, hi)

    @staticmethod
    def where(cond, a, b):
        if isinstance(a, BatchVec3):
            other = a.array.new_tensor(b) if isinstance(b, tuple) else b.array
            return BatchVec3(torch.where(cond, a.array, other))
        return torch.where(cond, a, b)

    @staticmethod
    def vec3(x, y, z) -> BatchVec3:
        like = next(v for v in (x, y, z) if not _is_const(v))
        cols = [v if not _is_const(v) else torch.full_like(like, v) for v in (x, y, z)]
        return BatchVec3(torch.cat(cols, dim=-1))

    @staticmethod
    def dot(a: BatchVec3, b: BatchVec3) -> torch.Tensor:
        return (a.array * b.array).sum(dim=-1, keepdim=True)

    @staticmethod
    def normalize(a: BatchVec3) -> BatchVec3:
        return BatchVec3(a.array / torch.linalg.vector_norm(a.array, dim=-1, keepdim=True))

    @staticmethod
    def as_vec3(v) -> BatchVec3:
        return v if isinstance(v, BatchVec3) else BatchVec3(v)

    @staticmethod
    def component(p, i: int):
        return p[i] if isinstance(p, (tuple, list)) else p[:, i : i + 1]


def _np_erf(x):
    from scipy.special import erf  # scipy: only where numpy formulas need erf (tests)

    return erf(x)


class _NumpyOps:
    """The vocabulary on numpy arrays: a second backend that keeps formulas backend-neutral."""

    name = "numpy"
    sqrt, exp, log, sin, cos, tan, abs = (staticmethod(f) for f in (np.sqrt, np.exp, np.log, np.sin, np.cos,
                                                                    np.tan, np.abs))
    erf = staticmethod(_np_erf)
    minimum = staticmethod(np.minimum)
    maximum = staticmethod(np.maximum)

    @staticmethod
    def clamp(x, lo: float | None = None, hi: float | None = None):
        return np.clip(x, lo, hi)

    @staticmethod
    def where(cond, a, b):
        if isinstance(a, BatchVec3):
            return BatchVec3(np.where(cond, a.array, np.asarray(b) if isinstance(b, tuple) else b.array))
        return np.where(cond, a, b)

    @staticmethod
    def vec3(x, y, z) -> BatchVec3:
        like = next(v for v in (x, y, z) if not _is_const(v))
        return BatchVec3(np.concatenate([np.broadcast_to(v, like.shape) for v in (x, y, z)], axis=-1))

    @staticmethod
    def dot(a, b):
        return (a.array * b.array).sum(axis=-1, keepdims=True)

    @staticmethod
    def normalize(a):
        return BatchVec3(a.array / np.linalg.norm(a.array, axis=-1, keepdims=True))

    as_vec3 = staticmethod(_TorchOps.as_vec3)
    component = staticmethod(_TorchOps.component)


TORCH = _TorchOps()
NUMPY = _NumpyOps()


# -- counting ----------------------------------------------------------------------------------------
class Counted:
    """A symbolic per-sample value of ``width`` components that counts the FLOPs spent on it:
    every element-wise op costs one FLOP per output component; ops among constants are free
    (they are folded before evaluation, as Python folds floats)."""

    __slots__ = ("width", "const", "tally")
    __array_ufunc__ = None
    __array_priority__ = 1000  # torch/numpy defer mixed arithmetic to Counted's reflected ops

    def __init__(self, width: int, tally: list[int], const: bool = False):
        self.width, self.tally, self.const = width, tally, const

    def _op(self, *others) -> "Counted":
        return _tally(self.tally, self, *others)

    __add__ = __radd__ = __sub__ = __rsub__ = __mul__ = __rmul__ = _op
    __truediv__ = __rtruediv__ = __pow__ = __rpow__ = _op
    __gt__ = __lt__ = __ge__ = __le__ = __and__ = __rand__ = __or__ = __ror__ = _op

    def __neg__(self) -> "Counted":
        return self._op()


def _tally(tally: list[int], *operands) -> Counted:
    """The result of one element-wise op on ``operands``, its FLOPs added to ``tally``."""
    width = max(o.width if isinstance(o, Counted) else 1 for o in operands)
    const = all(o.const for o in operands if isinstance(o, Counted))
    if not const:
        tally[0] += width
    return Counted(width, tally, const)


class CountedVec3:
    __slots__ = ("x", "y", "z", "tally")

    def __init__(self, tally: list[int], x=None, y=None, z=None):
        self.tally = tally
        self.x, self.y, self.z = (v if v is not None else Counted(1, tally) for v in (x, y, z))

    def _map(self, fn) -> "CountedVec3":
        return CountedVec3(self.tally, fn(self.x), fn(self.y), fn(self.z))

    def __add__(self, other):
        return CountedVec3(self.tally, self.x + other.x, self.y + other.y, self.z + other.z)

    def __sub__(self, other):
        return CountedVec3(self.tally, self.x - other.x, self.y - other.y, self.z - other.z)

    def __mul__(self, scalar):
        return self._map(lambda v: v * scalar)

    __rmul__ = __mul__

    def __truediv__(self, scalar):
        return self._map(lambda v: v / scalar)


class _CountOps:
    """The vocabulary on ``Counted`` values: FLOPs of a formula, for the specialized evaluator's cost."""

    name = "count"

    def __init__(self):
        self.tally = [0]

    def _fn(self, *args):
        return _tally(self.tally, *args)

    def __getattr__(self, name):
        if name in ("sqrt", "exp", "log", "sin", "cos", "tan", "erf", "abs", "minimum", "maximum"):
            return self._fn
        raise AttributeError(name)

    def clamp(self, x, lo=None, hi=None):
        return self._fn(x)

    def where(self, cond, a, b):
        if isinstance(a, CountedVec3):
            other = b if isinstance(b, CountedVec3) else CountedVec3(self.tally, *(self.constant(1) for _ in b))
            return CountedVec3(self.tally, *(self._fn(cond, u, v) for u, v in ((a.x, other.x), (a.y, other.y),
                                                                                 (a.z, other.z))))
        return self._fn(cond, a, b)

    def vec3(self, x, y, z) -> CountedVec3:
        return CountedVec3(self.tally, *(v if isinstance(v, Counted) else self.constant(1) for v in (x, y, z)))

    def dot(self, a, b):
        return a.x * b.x + a.y * b.y + a.z * b.z

    def normalize(self, a):
        return a / self.sqrt(self.dot(a, a))

    def as_vec3(self, v):
        return v

    def component(self, p, i: int):
        return self.constant(1) if not isinstance(p, Counted) or p.const else Counted(1, self.tally)

    def rotate(self, rotation, w: CountedVec3) -> CountedVec3:
        """``rotation @ w`` for a constant 3x3 matrix: 9 multiplies and 6 adds."""
        self.tally[0] += 15
        return CountedVec3(self.tally)

    def constant(self, width: int) -> Counted:
        """A value computed once (a folded parameter or term)."""
        return Counted(width, self.tally, const=True)

    def value(self, width: int) -> Counted:
        """A per-sample value computed elsewhere (e.g. a module's output, counted by the module)."""
        return Counted(width, self.tally)


def count_flops(fn) -> int:
    """FLOPs per sample of ``fn(xp, wi, wo)`` run once on the counting backend."""
    xp = _CountOps()
    fn(xp, CountedVec3(xp.tally), CountedVec3(xp.tally))
    return xp.tally[0]
