"""The optimisers that training, the paper's fit protocol, NBRDF fits and encoder training use:
RMSProp (the paper's, Sec. 5.1), Adam, and a cosine-annealed learning rate.

Each makes, operation for operation, the update its ``torch.optim`` counterpart makes on CPU
tensors — ``torch.optim.RMSprop`` without momentum or centring, ``torch.optim.Adam`` without weight
decay or AMSGrad (their single-tensor paths, which torch takes on CPU), and
``torch.optim.lr_scheduler.CosineAnnealingLR`` — so the numbers are the same to the last bit
(``tests/neuenh/test_optimizers.py`` checks them against torch's, step by step).

Why not torch's own: the first call of any ``torch.optim`` optimiser in a process imports
``torch._dynamo`` (its methods are wrapped by ``torch._disable_dynamo``, which imports it lazily),
about 1 s of CPU, and every process that trains pays it before its first step — each Ray worker,
each scene plan's process, each ``neuenh fit`` of NBRDF, the CLI's searches (docs/BENCHMARKS.md,
"Test suite time", stop 38).

The interface is the part of ``torch.optim`` these callers use: ``zero_grad()``, ``step()``, ``lr``.
A parameter without a gradient at a step is left as it is, its state too (as torch does).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from typing import Iterable

import torch

# Adam's constants (Kingma & Ba 2015, Alg. 1; PyTorch's defaults), also the row-wise fit's (``neuenh.fit.optim``).
ADAM_BETAS, ADAM_EPS = (0.9, 0.999), 1e-8


class Optimizer(ABC):
    """Parameters and a learning rate ``lr`` (a schedule may change it between steps)."""

    def __init__(self, params: Iterable[torch.Tensor], lr: float):
        self.params = list(params)
        if not self.params:
            raise ValueError("no parameters to optimise")
        if not lr >= 0:  # torch.optim's own precondition
            raise ValueError(f"the learning rate must not be negative, not {lr}")
        self.lr = float(lr)

    def zero_grad(self) -> None:
        """Drop every parameter's gradient (``torch.optim``'s ``set_to_none=True``)."""
        for p in self.params:
            p.grad = None

    @abstractmethod
    def step(self) -> None:
        """One update of every parameter that has a gradient."""


class RMSProp(Optimizer):
    """RMSProp (Tieleman & Hinton 2012, *Neural Networks for Machine Learning*, lecture 6.5), as
    ``torch.optim.RMSprop(params, lr, alpha, eps)``."""

    def __init__(self, params: Iterable[torch.Tensor], lr: float, alpha: float = 0.99, eps: float = 1e-8):
        super().__init__(params, lr)
        self.alpha, self.eps = alpha, eps
        self.square_avg = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]

    @torch.no_grad()
    def step(self) -> None:
        for p, square_avg in zip(self.params, self.square_avg):
            if p.grad is None:
                continue
            g = p.grad
            square_avg.mul_(self.alpha).addcmul_(g, g, value=1 - self.alpha)  # v <- alpha v + (1 - alpha) g^2
            p.addcdiv_(g, square_avg.sqrt().add_(self.eps), value=-self.lr)  # p <- p - lr g / (sqrt(v) + eps)


class Adam(Optimizer):
    """Adam (Kingma & Ba 2015, *Adam: A Method for Stochastic Optimization*, Algorithm 1), as
    ``torch.optim.Adam(params, lr, betas, eps)``; each parameter counts its own steps."""

    def __init__(self, params: Iterable[torch.Tensor], lr: float = 1e-3, betas: tuple[float, float] = ADAM_BETAS,
                 eps: float = ADAM_EPS):
        super().__init__(params, lr)
        self.betas, self.eps = betas, eps
        self.steps = [0] * len(self.params)
        self.exp_avg = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]
        self.exp_avg_sq = [torch.zeros_like(p, memory_format=torch.preserve_format) for p in self.params]

    @torch.no_grad()
    def step(self) -> None:
        beta1, beta2 = self.betas
        for i, p in enumerate(self.params):
            if p.grad is None:
                continue
            g = p.grad
            self.steps[i] += 1
            t = float(self.steps[i])
            self.exp_avg[i].lerp_(g, 1 - beta1)  # m <- beta1 m + (1 - beta1) g
            self.exp_avg_sq[i].mul_(beta2).addcmul_(g, g, value=1 - beta2)  # v <- beta2 v + (1 - beta2) g^2
            step_size = self.lr / (1 - beta1**t)  # m's bias correction, folded into the step
            denom = (self.exp_avg_sq[i].sqrt() / (1 - beta2**t) ** 0.5).add_(self.eps)  # sqrt(v-hat) + eps
            p.addcdiv_(self.exp_avg[i], denom, value=-step_size)


class CosineSchedule:
    """The optimiser's learning rate annealed to ``final`` along half a cosine over ``steps`` calls
    of ``step()`` (Loshchilov & Hutter 2017, *SGDR*, eq. 5, without restarts), by the recursion
    ``torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=steps, eta_min=final)`` uses —
    the same floats, not the closed form's. ``steps`` may be 0 (a run of no epochs), but such a
    schedule cannot step."""

    def __init__(self, optimizer: Optimizer, steps: int, final: float = 0.0):
        if steps < 0:
            raise ValueError(f"a schedule's steps must not be negative, not {steps}")
        self.optimizer, self.steps, self.final = optimizer, steps, final
        self.base = optimizer.lr
        self.epoch = 0

    def step(self) -> None:
        if not self.steps:
            raise ValueError("a schedule of 0 steps cannot step")
        self.epoch += 1
        e, n, lr, final = self.epoch, self.steps, self.optimizer.lr, self.final
        if (e - 1 - n) % (2 * n) == 0:  # past the trough the recursion's ratio is 0/0: torch's own special case
            self.optimizer.lr = lr + (self.base - final) * (1 - math.cos(math.pi / n)) / 2
        else:
            self.optimizer.lr = (1 + math.cos(math.pi * e / n)) / (1 + math.cos(math.pi * (e - 1) / n)) * (lr - final) + final
