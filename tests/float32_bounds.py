"""Error bounds of float32 evaluations that follow from the arithmetic, not from one CPU's printout.

A float32 evaluation of f_r (torch's, an exported shader's, an ONNX graph's, Dr.Jit's) differs from
the float64 value at the same float32 directions by rounding, bounded per row and relative to |f_r|
(first order; Higham, "Accuracy and Stability of Numerical Algorithms", 2002, Sec. 3.1 and 3.4) by

    |f32 - f64| / |f64|  <=  u (C kappa + n)  +  C e32

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
* ``C = 4`` covers transcendental functions that round to a few ulps rather than half of one
  (GLSL's and Dr.Jit's exp, log, pow) and the independent roundings of the two inputs.

It holds on any CPU or GPU that rounds each operation to float32, with or without fused
multiply-adds or another vector width. Values below ``FLOOR`` of the largest |f_r| are compared
relative to that floor.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch

U32 = 2.0**-24  # float32 unit roundoff
NUDGE_ULPS = 2.0  # directions moved by this many float32 ulps per component to measure the condition
CONDITION_FACTOR = 4.0  # C above
TRIALS = 3  # nudged copies of the directions
FLOOR = 1e-3  # relative errors are taken against max(|f|, FLOOR * max |f|)

Evaluate = Callable[[torch.Tensor, torch.Tensor], np.ndarray]


def nudge(w: torch.Tensor, seed: int) -> torch.Tensor:
    """``w`` (float64) moved by ``NUDGE_ULPS`` float32 ulps per component (random signs), renormalized."""
    sign = torch.randint(0, 2, w.shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64) * 2 - 1
    return torch.nn.functional.normalize(w * (1 + sign * NUDGE_ULPS * 2.0**-23), dim=1)


def scale_of(truth: np.ndarray) -> np.ndarray:
    """What each value's error is relative to: |f|, or ``FLOOR`` of the largest |f| — or the smallest
    normal float64 where f_r is 0 everywhere (a black material): there any non-zero value fails."""
    floor = max(FLOOR * float(np.abs(truth).max(initial=0.0)), np.finfo(np.float64).tiny)
    return np.maximum(np.abs(truth), floor)


def row_error(got: np.ndarray, truth: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Each row's largest relative error of ``got`` against ``truth``."""
    return (np.abs(np.asarray(got, np.float64) - truth) / scale).max(1)


def relative_bound(float64: Evaluate, float32: Evaluate, wi: torch.Tensor, wo: torch.Tensor,
                   n_ops: int) -> tuple[np.ndarray, np.ndarray]:
    """(float64 f_r at the float32 directions ``wi, wo`` (n, 3), the per-row relative bound (n,)).
    ``float64(wi, wo)``: the reference evaluation in float64; ``float32(wi, wo)``: the reference
    float32 path (torch's) at float32 directions; both return (n, 3) numpy."""
    truth = float64(wi.double(), wo.double())
    scale = scale_of(truth)
    move = NUDGE_ULPS * 2.0**-23  # the relative move of each component
    kappa = np.zeros(len(truth))
    own = row_error(float32(wi.float(), wo.float()), truth, scale)
    for trial in range(TRIALS):
        wi_moved, wo_moved = nudge(wi.double(), 2 * trial), nudge(wo.double(), 2 * trial + 1)
        moved = float64(wi_moved, wo_moved)
        kappa = np.maximum(kappa, row_error(moved, truth, scale) / move)
        wi32, wo32 = wi_moved.float(), wo_moved.float()  # another rounding of nearly the same point
        own = np.maximum(own, row_error(float32(wi32, wo32), float64(wi32.double(), wo32.double()), scale))
    return truth, U32 * (CONDITION_FACTOR * kappa + n_ops) + CONDITION_FACTOR * own


def assert_within(got: np.ndarray, truth: np.ndarray, bound: np.ndarray, what: str) -> None:
    """Every row's largest relative error (against ``scale_of(truth)``) within its bound."""
    error = row_error(got, truth, scale_of(truth))
    worst = int(np.argmax(error / bound))
    assert (error <= bound).all(), (f"{what}: relative error {error[worst]:.3g} > its bound {bound[worst]:.3g} "
                                    f"(row {worst}; {int((error > bound).sum())} rows over)")
