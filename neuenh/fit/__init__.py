"""Fit new materials with a trained model: module weights frozen, per-material parameters free.

``fit_materials(model, samples, protocol)`` runs a fit protocol (``protocols``: the paper's RMSProp,
plain L-BFGS, the latent fit, the adaptive-capacity fit) on every material of ``samples``.
The pieces: ``layout`` (the rows of a fit side by side), ``kernel`` (every row's loss and gradient
through the frozen modules, with per-row corrections), ``optim`` (row-wise Adam and L-BFGS),
``capacity`` (corrections and the cross-validated choice of capacity), ``run`` (the protocol over
blocks of materials, so that memory stays bounded). ``fit_in_processes`` splits the materials over
several processes.
"""

from __future__ import annotations

from .capacity import CAPACITIES, Adaptive
from .kernel import frozen
from .optim import SURROGATE_EPS
from .options import FitOptions
from .parallel import fit_in_processes
from .protocols import FitProtocol, LatentAdam, PaperRMSProp, PlainLBFGS
from .result import FitResult, losses_at_own_capacity, material_model, model_for, per_material_loss
from .run import default_protocol, fit_materials

__all__ = ["Adaptive", "CAPACITIES", "FitOptions", "FitProtocol", "FitResult", "LatentAdam", "PaperRMSProp",
           "PlainLBFGS", "SURROGATE_EPS", "default_protocol", "fit_in_processes", "fit_materials", "frozen", "losses_at_own_capacity",
           "material_model", "model_for", "per_material_loss"]
