"""Row-wise L-BFGS (``neuenh.lbfgs``) against closed-form minimisers, and the independence of rows."""

from __future__ import annotations

import torch

from neuenh.lbfgs import minimize_rows


def rosenbrock(x: torch.Tensor, rows: torch.Tensor):
    """Per row, the d-dimensional Rosenbrock function; its minimum is 0 at (1, ..., 1)."""
    x = x.detach().requires_grad_(True)
    f = ((1 - x[:, :-1]) ** 2 + 100 * (x[:, 1:] - x[:, :-1] ** 2) ** 2).sum(1)
    (g,) = torch.autograd.grad(f.sum(), x)
    return f.detach(), g


STARTS = torch.tensor([[-1.2, 1.0, -1.2, 1.0], [0.0, 0.0, 0.0, 0.0], [2.0, 2.0, -0.5, 3.0]], dtype=torch.float64)


def test_rosenbrock_rows_reach_the_minimum():
    result = minimize_rows(rosenbrock, STARTS, max_iter=300, rel_tol=1e-14, patience=3)
    assert torch.allclose(result.x, torch.ones_like(STARTS), atol=1e-5)
    assert (result.loss < 1e-10).all()
    assert result.evaluations < 300  # quasi-Newton, not a crawl (steepest descent needs thousands)


def test_convex_quadratics_reach_their_closed_form_minimisers():
    """f_r(x) = 1/2 x'A_r x - b_r'x with A_r symmetric positive definite: minimiser A_r^-1 b_r."""
    generator = torch.Generator().manual_seed(0)
    rows, dim = 5, 12
    q = torch.linalg.qr(torch.randn(rows, dim, dim, generator=generator, dtype=torch.float64)).Q
    spectrum = torch.logspace(-2, 2, dim, dtype=torch.float64)  # condition number 1e4
    a = q @ torch.diag_embed(spectrum.expand(rows, dim)) @ q.transpose(1, 2)
    b = torch.randn(rows, dim, generator=generator, dtype=torch.float64)

    def quadratic(x, wanted):
        ax = (a @ x[:, :, None])[:, :, 0]
        return 0.5 * (x * ax).sum(1) - (b * x).sum(1), ax - b

    result = minimize_rows(quadratic, torch.zeros(rows, dim, dtype=torch.float64), max_iter=500,
                           history=20, rel_tol=1e-15, patience=5)
    want = torch.linalg.solve(a, b)
    assert float((result.x - want).abs().max() / want.abs().max()) < 1e-6


def test_a_row_is_minimised_the_same_alone_or_among_others():
    """Step lengths, curvature pairs and stopping are per row: a row's iterates do not depend on
    the rows beside it (bit-identical)."""
    together = minimize_rows(rosenbrock, STARTS, max_iter=60)
    for i in range(len(STARTS)):
        alone = minimize_rows(rosenbrock, STARTS[i : i + 1], max_iter=60)
        assert torch.equal(alone.x[0], together.x[i])
        assert alone.iterations[0] == together.iterations[i]


def test_a_row_with_an_infinite_loss_is_left_where_it_started():
    def objective(x, rows):
        f, g = rosenbrock(x, rows)
        return torch.where(torch.arange(len(x)) == 1, torch.inf, f), g

    result = minimize_rows(objective, STARTS, max_iter=50)
    assert torch.equal(result.x[1], STARTS[1])
    assert result.iterations[1] == 0 and result.loss[0] < rosenbrock(STARTS[:1], None)[0][0]


def _failing_from(first_failure: int, failures: int):
    """Rosenbrock whose evaluations number ``first_failure`` .. ``first_failure + failures - 1``
    (1 = the start's) return a NaN loss: a line search that falls in that window fails."""
    count = [0]

    def objective(x, rows):
        count[0] += 1
        f, g = rosenbrock(x, rows)
        return (f * torch.nan if first_failure <= count[0] < first_failure + failures else f), g

    return objective


def test_a_failed_quasi_newton_line_search_restarts_from_steepest_descent():
    """A line search along a step from the curvature memory that finds no decrease (here: every trial
    NaN, 12 backtracks) clears the memory and the row goes on by steepest descent, to the minimum;
    before, such a row stopped where it was (Nocedal & Wright Sec. 7.2)."""
    start = STARTS[:1]
    clean = minimize_rows(rosenbrock, start, max_iter=300, rel_tol=1e-14)
    # evaluation 1 is the start's, 2 and on the first iterations' trials: the window from 6 on falls
    # in a line search along a quasi-Newton step (the first iteration's is steepest descent)
    result = minimize_rows(_failing_from(6, 12), start, max_iter=300, rel_tol=1e-14)
    assert clean.loss[0] < 1e-10 and result.loss[0] < 1e-10


def test_a_failed_steepest_descent_line_search_stops_the_row():
    result = minimize_rows(_failing_from(2, 12), STARTS[:1], max_iter=50)
    assert torch.equal(result.x, STARTS[:1]) and result.iterations[0] == 1 and result.evaluations == 13
