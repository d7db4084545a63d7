"""Error bounds of float32 evaluations that follow from the arithmetic, not from one CPU's printout.

A float32 evaluation of f_r (torch's, an exported shader's, an ONNX graph's, Dr.Jit's) differs from
the float64 value at the same float32 directions by rounding, bounded per row and relative to |f_r|
(first order; Higham, "Accuracy and Stability of Numerical Algorithms", 2002, Sec. 3.1 and 3.4) by

    |f32 - f64| / |f64|  <=  u (C (kappa + kappa_s) + n)  +  C e32  (+ e_fn)

* ``u = 2^-24``, float32's unit roundoff; ``n`` the operations of one evaluation
  (``SpecializedBRDF.flops_per_evaluation``): each rounds once;
* ``kappa``, the condition of f_r in its inputs, measured in float64 as the relative change of f_r
  when the directions move by ``NUDGE_ULPS`` float32 ulps per component (random signs), divided by
  that relative move: how much the rounding of what the evaluation reads is amplified;
* ``e32``, the rounding of the intermediates amplified by what follows them (a half vector's cos
  rounded near 1 then raised to a sharp lobe's power; exp of a large exponent), which kappa does not
  see where f_r is stationary in its inputs (at the mirror direction): the reference float32 path's
  own error measured in the same test, per row, as its largest over the row's own directions and
  ``TRIALS`` nudged copies (each rounds differently), so no single lucky row sets it;
* ``kappa_s`` (for an evaluation that computes the shading quantities in another order than the
  reference path: an exported artifact), the condition of f_r in the shading-frame directions, the
  half vector and the cosines, measured in float64 like kappa by moving them (``moved_shading``).
  e32 alone is not enough there: near a sharp lobe's peak cos_h is stationary, so where its exact
  value lies near a float32 number torch's float32 path rounds it almost exactly at every nudge
  (measured: 0.005 ulp; Blinn-Phong, e = 1543) while onnxruntime's own normalization is an ulp off,
  which the exponent turns into 9e-5;
* ``C = 4`` covers functions that round to a few ulps rather than half of one (Dr.Jit's and
  onnxruntime's exp, log) and the independent roundings of the two inputs;
* ``e_fn`` (for a runtime documented to be less accurate than that, GLSL: ``FunctionAccuracy``),
  the largest change of float64 f_r when its exp, log and sqrt are moved by the documented worst case
  (``moved_functions``: all up, all down, random signs): GLSL's log may be 2^-21 off near 1, which a
  Blinn-Phong exponent of 1e4 turns into 5e-3.

It holds on any CPU or GPU that rounds each operation to float32, with or without fused
multiply-adds or another vector width. Values below ``FLOOR`` of the largest |f_r| are compared
relative to that floor.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from typing import Callable, ContextManager

import numpy as np
import torch

U32 = 2.0**-24  # float32 unit roundoff
NUDGE_ULPS = 2.0  # directions moved by this many float32 ulps per component to measure the condition
CONDITION_FACTOR = 4.0  # C above
TRIALS = 3  # nudged copies of the directions
FLOOR = 1e-3  # relative errors are taken against max(|f|, FLOOR * max |f|)

Evaluate = Callable[[torch.Tensor, torch.Tensor], np.ndarray]
COSINES = ("cos_i", "cos_o", "cos_h", "cos_d")  # the Shading fields that are cosines


def nudge(w: torch.Tensor, seed: int) -> torch.Tensor:
    """``w`` (float64) moved by ``NUDGE_ULPS`` float32 ulps per component (random signs), renormalized."""
    sign = torch.randint(0, 2, w.shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64) * 2 - 1
    return torch.nn.functional.normalize(w * (1 + sign * NUDGE_ULPS * 2.0**-23), dim=1)


@contextlib.contextmanager
def moved_shading(seed: int):
    """Within it, the shading of ``evaluate`` and of the specialized evaluator (``shade(xp, wi, wo,
    wi_s, wo_s, params)`` as ``neuenh.shading`` and ``neuenh.specialize`` call it) reads shading-frame directions ``wi_s, wo_s`` whose components are each
    moved by ``NUDGE_ULPS`` float32 ulps of the vector's length (what rounding the rotation into the
    shading frame leaves), and its half vector's components and its cosines are each moved by
    ``NUDGE_ULPS`` ulps of themselves (cosines kept <= 1); random signs."""
    import neuenh.shading as shading
    import neuenh.specialize as specialize
    from neuenh.ops import BatchVec3

    original, generator = shading.shade, torch.Generator().manual_seed(seed)
    step = NUDGE_ULPS * 2.0**-23

    def sign(x: torch.Tensor) -> torch.Tensor:
        return torch.randint(0, 2, x.shape, generator=generator, dtype=x.dtype) * 2 - 1

    def rotated(w: BatchVec3) -> BatchVec3:
        return BatchVec3(w.array + sign(w.array) * step * torch.linalg.vector_norm(w.array, dim=-1, keepdim=True))

    def relative(x, at_most=None):
        if isinstance(x, BatchVec3):
            return BatchVec3(relative(x.array))
        x = x * (1 + sign(x) * step)
        return x if at_most is None else x.clamp(max=at_most)

    def shade(xp, wi, wo, wi_s, wo_s, params):
        s = original(xp, wi, wo, rotated(wi_s), rotated(wo_s), params)
        return dataclasses.replace(s, h=relative(s.h), **{f: relative(getattr(s, f), 1.0) for f in COSINES})

    specialize.shade = shading.shade = shade
    try:
        yield
    finally:
        specialize.shade = shading.shade = original


@dataclasses.dataclass(frozen=True)
class FunctionAccuracy:
    """A runtime's documented worst case for its built-in functions, in float32 ULPs (2^-23 of the
    value) unless said: ``exp(x)`` within ``exp_ulps + exp_ulps_per_x |x|``; ``log(x)`` within
    ``log_absolute`` (an absolute error) for x in [0.5, 2], else ``log_ulps``; ``sqrt`` within
    ``sqrt_ulps``."""

    exp_ulps: float
    exp_ulps_per_x: float
    log_absolute: float
    log_ulps: float
    sqrt_ulps: float


@contextlib.contextmanager
def moved_functions(accuracy: FunctionAccuracy, sign: float | None, seed: int = 0):
    """Within it, the torch vocabulary's ``exp``, ``log`` and ``sqrt`` (``neuenh.ops.TORCH``, what
    every formula calls) on tensors return values moved by ``accuracy``'s worst case: up (``sign``
    1), down (-1) or with random signs (None)."""
    from neuenh.ops import TORCH

    generator, ulp = torch.Generator().manual_seed(seed), 2.0**-23

    def signs(y: torch.Tensor):
        if sign is not None:
            return sign
        return torch.randint(0, 2, y.shape, generator=generator, dtype=y.dtype) * 2 - 1

    def exp(x):
        y = torch.exp(x)
        return y * (1 + signs(y) * (accuracy.exp_ulps + accuracy.exp_ulps_per_x * x.abs()) * ulp)

    def log(x):
        y = torch.log(x)
        inside = (x >= 0.5) & (x <= 2.0)
        return y + signs(y) * torch.where(inside, accuracy.log_absolute, accuracy.log_ulps * ulp * y.abs())

    def sqrt(x):
        y = torch.sqrt(x)
        return y * (1 + signs(y) * accuracy.sqrt_ulps * ulp)

    originals = {"exp": (math.exp, exp), "log": (math.log, log), "sqrt": (math.sqrt, sqrt)}
    for name, (const_fn, tensor_fn) in originals.items():
        setattr(TORCH, name, lambda x, const_fn=const_fn, tensor_fn=tensor_fn:
                const_fn(x) if not isinstance(x, torch.Tensor) else tensor_fn(x))
    try:
        yield
    finally:
        for name in originals:
            delattr(TORCH, name)  # the class's own functions again


def scale_of(truth: np.ndarray) -> np.ndarray:
    """What each value's error is relative to: |f|, or ``FLOOR`` of the largest |f| — or the smallest
    normal float64 where f_r is 0 everywhere (a black material): there any non-zero value fails."""
    floor = max(FLOOR * float(np.abs(truth).max(initial=0.0)), np.finfo(np.float64).tiny)
    return np.maximum(np.abs(truth), floor)


def row_error(got: np.ndarray, truth: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Each row's largest relative error of ``got`` against ``truth``."""
    return (np.abs(np.asarray(got, np.float64) - truth) / scale).max(1)


@dataclasses.dataclass(frozen=True)
class Measured:
    """What ``measure`` finds at a set of float32 directions, per row: float64 f_r (``truth``), what
    errors are relative to (``scale_of(truth)``), kappa, kappa_s and e32 (the module docstring)."""

    truth: np.ndarray
    scale: np.ndarray
    kappa: np.ndarray
    kappa_s: np.ndarray
    own: np.ndarray

    def bound(self, n_ops: int, factor: float = CONDITION_FACTOR, e_fn: np.ndarray | float = 0.0) -> np.ndarray:
        """The per-row relative bound u (C (kappa + kappa_s) + n) + C e32 + e_fn."""
        return U32 * (factor * (self.kappa + self.kappa_s) + n_ops) + factor * self.own + e_fn


def measure(float64: Evaluate, float32: Evaluate, wi: torch.Tensor, wo: torch.Tensor,
            moved_intermediates: Callable[[int], ContextManager] | None = None) -> Measured:
    """``float64(wi, wo)``: the reference evaluation in float64; ``float32(wi, wo)``: the reference
    float32 path (torch's) at float32 directions; both return (n, 3) numpy. ``moved_intermediates(seed)``:
    a context within which ``float64`` runs with its intermediates moved (``moved_shading``), for
    kappa_s; without it kappa_s = 0 (the evaluation under test rounds as the reference path does)."""
    truth = float64(wi.double(), wo.double())
    scale = scale_of(truth)
    move = NUDGE_ULPS * 2.0**-23  # the relative move of each component
    kappa, kappa_s = np.zeros(len(truth)), np.zeros(len(truth))
    own = row_error(float32(wi.float(), wo.float()), truth, scale)
    for trial in range(TRIALS):
        wi_moved, wo_moved = nudge(wi.double(), 2 * trial), nudge(wo.double(), 2 * trial + 1)
        moved = float64(wi_moved, wo_moved)
        kappa = np.maximum(kappa, row_error(moved, truth, scale) / move)
        if moved_intermediates is not None:
            with moved_intermediates(trial):
                kappa_s = np.maximum(kappa_s, row_error(float64(wi.double(), wo.double()), truth, scale) / move)
        wi32, wo32 = wi_moved.float(), wo_moved.float()  # another rounding of nearly the same point
        own = np.maximum(own, row_error(float32(wi32, wo32), float64(wi32.double(), wo32.double()), scale))
    return Measured(truth, scale, kappa, kappa_s, own)


def function_error(float64: Evaluate, wi: torch.Tensor, wo: torch.Tensor, measured: Measured,
                   functions: FunctionAccuracy) -> np.ndarray:
    """e_fn: float64's largest relative change, per row, with its functions moved by ``functions``'
    worst case (``moved_functions``: all up, all down, random signs)."""
    e_fn = np.zeros(len(measured.truth))
    for trial, sign in enumerate((1.0, -1.0, None)):
        with moved_functions(functions, sign, seed=trial):
            e_fn = np.maximum(e_fn, row_error(float64(wi.double(), wo.double()), measured.truth, measured.scale))
    return e_fn


def relative_bound(float64: Evaluate, float32: Evaluate, wi: torch.Tensor, wo: torch.Tensor,
                   n_ops: int, factor: float = CONDITION_FACTOR,
                   moved_intermediates: Callable[[int], ContextManager] | None = None,
                   functions: FunctionAccuracy | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(float64 f_r at the float32 directions ``wi, wo`` (n, 3), the per-row relative bound (n,)):
    ``measure``, then ``Measured.bound`` with ``factor`` as C (the evaluation under test's functions
    round to that many times the reference path's) and, with ``functions`` (the evaluation under
    test's documented function accuracy, where it is worse than a few ulps), ``function_error``."""
    measured = measure(float64, float32, wi, wo, moved_intermediates)
    e_fn = 0.0 if functions is None else function_error(float64, wi, wo, measured, functions)
    return measured.truth, measured.bound(n_ops, factor, e_fn)


def assert_within(got: np.ndarray, truth: np.ndarray, bound: np.ndarray, what: str) -> None:
    """Every row's largest relative error (against ``scale_of(truth)``) within its bound."""
    error = row_error(got, truth, scale_of(truth))
    worst = int(np.argmax(error / bound))
    assert (error <= bound).all(), (f"{what}: relative error {error[worst]:.3g} > its bound {bound[worst]:.3g} "
                                    f"(row {worst}; {int((error > bound).sum())} rows over)")
