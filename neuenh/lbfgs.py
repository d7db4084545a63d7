"""Row-wise L-BFGS: many independent small problems minimised together, one batch per evaluation.

Fitting materials is a set of independent problems (each material's own 12 + latent parameters,
its own samples), and so is every start of a fit. Stacking them as the rows of one table lets a
single forward and backward pass evaluate every row's loss and gradient at once; ``minimize_rows``
then runs an independent L-BFGS per row (Nocedal & Wright 2006, *Numerical Optimization*,
Alg. 7.4 two-loop recursion and Alg. 7.5, with the initial Hessian scaling of eq. 7.20) with a
per-row backtracking Armijo line search (their Alg. 3.1), so a row's step length, curvature history
and convergence never depend on another row's. A row stops once its loss has fallen by less than
``rel_tol`` of itself for ``patience`` iterations in a row, or when a line search along its steepest
descent finds no decrease (one along a quasi-Newton step clears the row's curvature memory instead,
their Sec. 7.2, and the row goes on); the whole minimisation stops when every row has, or after
``max_iter`` iterations.

Everything is vectorised over rows and deterministic (same inputs, same iterates).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

# f(x, rows) -> (per-row loss (R,), gradient (R, d)); rows must be independent (row r's loss reads
# x[r] only). ``rows`` (R,) bool marks the rows whose loss and gradient are wanted: the objective may
# skip the others' work and return anything finite for them (a line search re-evaluates only the
# rows still backtracking).
RowObjective = Callable[[torch.Tensor, torch.Tensor], tuple[torch.Tensor, torch.Tensor]]

ARMIJO = 1e-4  # sufficient-decrease constant c1 (Nocedal & Wright, Sec. 3.1)
CURVATURE_EPS = 1e-10  # a pair with s.y below this (relative) is skipped, keeping H positive definite


@dataclass
class RowResult:
    x: torch.Tensor  # (R, d) the minimiser found per row
    loss: torch.Tensor  # (R,) its loss
    iterations: torch.Tensor  # (R,) iterations each row ran before it stopped
    evaluations: int  # objective evaluations (batched: one per forward + backward)


def minimize_rows(
    objective: RowObjective,
    x0: torch.Tensor,
    *,
    max_iter: int = 100,
    history: int = 10,
    rel_tol: float = 1e-4,
    patience: int = 3,
    max_backtracks: int = 12,
    first_step: float = 0.1,
) -> RowResult:
    """Minimise every row of ``x0`` (R, d) independently (see the module doc). ``first_step``:
    the length of each row's first step, along its steepest descent (no curvature is known yet)."""
    x = x0.detach().clone()
    rows, dim = x.shape
    loss, grad = objective(x, torch.ones(rows, dtype=torch.bool))
    evaluations = 1
    s_hist = torch.zeros(history, rows, dim, dtype=x.dtype)
    y_hist = torch.zeros_like(s_hist)
    rho = torch.zeros(history, rows, dtype=x.dtype)  # 0 marks an empty or skipped pair: a no-op
    gamma = torch.zeros(rows, dtype=x.dtype)  # initial Hessian scale s.y / y.y; 0 = no curvature yet
    active = torch.isfinite(loss)
    quiet = torch.zeros(rows, dtype=torch.long)  # iterations in a row with a negligible decrease
    iterations = torch.zeros(rows, dtype=torch.long)
    for it in range(max_iter):
        if not active.any():
            break
        direction = -_two_loop(grad, s_hist, y_hist, rho, gamma, it, history)
        # No curvature yet (or a reset): a steepest-descent step of length first_step.
        fresh = gamma == 0
        norm = torch.linalg.vector_norm(grad, dim=1).clamp_min(1e-30)
        direction = torch.where(fresh[:, None], -grad * (first_step / norm)[:, None], direction)
        slope = (grad * direction).sum(1)
        uphill = slope >= 0  # numerically not a descent direction: restart that row's memory
        if uphill.any():
            direction = torch.where(uphill[:, None], -grad * (first_step / norm)[:, None], direction)
            slope = (grad * direction).sum(1)
            rho[:, uphill] = 0
            gamma[uphill] = 0
        step = torch.where(active, 1.0, 0.0).to(x.dtype)
        pending = active.clone()
        new_x, new_loss, new_grad = x.clone(), loss.clone(), grad.clone()
        for _ in range(max_backtracks):
            trial = x + step[:, None] * direction
            trial_loss, trial_grad = objective(torch.where(pending[:, None], trial, new_x), pending)
            evaluations += 1
            finite = torch.isfinite(trial_loss)
            accept = pending & finite & (trial_loss <= loss + ARMIJO * step * slope)
            new_x = torch.where(accept[:, None], trial, new_x)
            new_loss = torch.where(accept, trial_loss, new_loss)
            new_grad = torch.where(accept[:, None], trial_grad, new_grad)
            pending &= ~accept
            if not pending.any():
                break
            # The minimiser of the quadratic through f(0), f'(0) and f(step) (Nocedal & Wright
            # eq. 3.57), kept within [0.1, 0.5] of the step so backtracking neither stalls nor jumps.
            excess = (trial_loss - loss - slope * step).clamp_min(1e-300)
            quadratic = torch.where(finite, -slope * step * step / (2 * excess), 0.1 * step)
            step = torch.where(pending, quadratic.clamp(0.1 * step, 0.5 * step), step)
        # A row whose line search failed keeps its point. If the step came from its curvature memory,
        # the memory is stale (Nocedal & Wright Sec. 7.2: restart): it is cleared and the row tries a
        # steepest-descent step next; a failed steepest-descent step stops the row.
        failed = pending & fresh
        restart = pending & ~fresh
        s, y = new_x - x, new_grad - grad
        sy = (s * y).sum(1)
        good = active & ~failed & (sy > CURVATURE_EPS * torch.linalg.vector_norm(s, dim=1)
                                   * torch.linalg.vector_norm(y, dim=1))
        slot = it % history
        s_hist[slot], y_hist[slot] = s, y
        rho[slot] = torch.where(good, 1.0 / torch.where(good, sy, 1.0), 0.0)
        gamma = torch.where(good, sy / (y * y).sum(1).clamp_min(1e-30), gamma)
        if restart.any():
            rho[:, restart] = 0
            gamma[restart] = 0
        decrease = loss - new_loss
        quiet = torch.where(decrease <= rel_tol * new_loss.abs().clamp_min(1e-12), quiet + 1, 0)
        iterations += active.long()
        x, loss, grad = new_x, new_loss, new_grad
        active &= ~failed & (quiet < patience)
    return RowResult(x, loss, iterations, evaluations)


def _two_loop(grad: torch.Tensor, s_hist: torch.Tensor, y_hist: torch.Tensor, rho: torch.Tensor,
              gamma: torch.Tensor, it: int, history: int) -> torch.Tensor:
    """H grad by the two-loop recursion (Nocedal & Wright Alg. 7.4), per row; newest pair first."""
    q = grad.clone()
    order = [(it - 1 - k) % history for k in range(min(it, history))]
    alpha = {}
    for slot in order:
        alpha[slot] = rho[slot] * (s_hist[slot] * q).sum(1)
        q -= alpha[slot][:, None] * y_hist[slot]
    r = gamma[:, None] * q
    for slot in reversed(order):
        beta = rho[slot] * (y_hist[slot] * r).sum(1)
        r += s_hist[slot] * (alpha[slot] - beta)[:, None]
    return r
