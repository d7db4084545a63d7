"""What a user asks of a fit, and the protocol that does it for a given model.

``FitOptions`` is the one place where options — from ``neuenh fit``, ``POST /v1/jobs/{id}/fit``, a
scene's ``fit:`` or the report — become a protocol object (``protocol_for(model)``); the protocols
themselves own their budgets. Budgets have one meaning each: ``epochs`` counts epochs of a
first-order method (Adam, RMSProp; NBRDF's fit reads it too), ``lbfgs_iterations`` counts L-BFGS
iterations per surrogate phase (plain models; ``epochs`` when it is not given, a plain fit's only
budget).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..capacities import CAPACITY_CHOICES
from ..model import BRDFModel
from .capacity import Adaptive
from .jit import KERNELS
from .jit import available as jit_available
from .protocols import FitProtocol, LatentAdam, PaperRMSProp, PlainLBFGS

METHODS = ("fast", "paper")


@dataclass(frozen=True)
class FitOptions:
    """``method``: ``fast`` (default) or ``paper`` (the paper's RMSProp protocol, latent capacity).
    ``capacity`` (models with modules, fast method): ``auto`` chooses per material by validation on
    its own samples (``capacity.Adaptive``), a capacity name fits that capacity only.
    ``epochs``/``lbfgs_iterations``: budgets (module doc), None for each protocol's own.
    ``kernel`` (fast method): ``torch`` or ``jit``, the fits' compiled Dr.Jit kernel (``neuenh.fit.jit``)
    for the rows it applies to, "jit" without Dr.Jit an error here; None (default): each protocol's own —
    "auto" for the latent fit (jit for fits of at least ``jit.JIT_MIN_WORK`` measurement-epochs where Dr.Jit
    is available, else torch), torch for the plain and adaptive fits."""

    method: str = "fast"
    # the library's default, not the users' ("auto", ``neuenh.capacities.USER_CAPACITY``): the fits inside
    # the product name their capacity (a search's fit score, a scene's rungs, the report's contenders) or
    # are quick looks (``neuenh data slice``), and the adaptive fit costs about twice the latent one
    capacity: str = "latent"
    epochs: int | None = None
    lbfgs_iterations: int | None = None
    starts: str = "analytical"
    kernel: str | None = None

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"fit method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.capacity not in CAPACITY_CHOICES:
            raise ValueError(f"capacity must be one of {', '.join(CAPACITY_CHOICES)}, got {self.capacity!r}")
        if self.starts not in ("analytical", "paper"):
            raise ValueError(f"fit starts must be 'analytical' or 'paper', got {self.starts!r}")
        if self.kernel is not None and self.kernel not in KERNELS:
            raise ValueError(f"fit kernel must be one of {', '.join(KERNELS)}, got {self.kernel!r}")
        if self.kernel == "jit" and not jit_available():
            raise ValueError("the jit fit kernel needs Dr.Jit's LLVM backend: pip install 'neuenh[export]' and a "
                             "libLLVM 17 or newer (Debian 12: apt-get install libllvm19; make mitsuba)")
        for name in ("epochs", "lbfgs_iterations"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"{name} must be at least 1, got {value}")

    def protocol_for(self, model: BRDFModel) -> FitProtocol:
        """The protocol these options name for ``model``."""
        if self.method == "paper":
            return PaperRMSProp(**_given(epochs=self.epochs))
        if not model.has_modules:
            # a plain model's only budget: --epochs stands for it unless lbfgs_iterations is given
            return PlainLBFGS(**_given(iterations=self.lbfgs_iterations or self.epochs, kernel=self.kernel))
        if self.capacity == "latent":
            return LatentAdam(**_given(epochs=self.epochs, kernel=self.kernel), starts=self.starts)
        capacities = {} if self.capacity == "auto" else {"capacities": (self.capacity,)}
        budget = {} if self.epochs is None else {"latent_epochs": self.epochs,
                                                 "correction_epochs": max(1, self.epochs // 2)}
        return Adaptive(**capacities, **_given(lbfgs_iterations=self.lbfgs_iterations, kernel=self.kernel), **budget,
                        latent_starts=self.starts)

    def replace(self, **changes) -> "FitOptions":
        return dataclasses.replace(self, **changes)


def _given(**budgets) -> dict:
    return {k: v for k, v in budgets.items() if v is not None}
