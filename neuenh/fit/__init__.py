"""Fit new materials with a trained model: module weights frozen, per-material parameters free.

``fit_materials(model, samples, protocol)`` runs a fit protocol (``protocols``: the paper's RMSProp,
plain L-BFGS, the latent fit, the adaptive-capacity fit) on every material of ``samples`` at once.
The pieces: ``layout`` (the rows of a fit side by side), ``kernel`` (every row's loss and gradient
through the frozen modules, with per-row corrections), ``optim`` (row-wise Adam and L-BFGS),
``capacity`` (corrections and the cross-validated choice of capacity). ``fit_in_processes`` splits
the materials over several processes.
"""

from __future__ import annotations

from ..data.samples import Samples
from ..encoder import MaterialEncoder
from ..materials import MaterialTable
from ..model import BRDFModel
from .capacity import CAPACITIES, Adaptive
from .kernel import frozen
from .optim import SURROGATE_EPS
from .options import FitOptions
from .parallel import fit_in_processes
from .protocols import FitProtocol, LatentAdam, PaperRMSProp, PlainLBFGS
from .result import FitResult, losses_at_own_capacity, material_model, model_for, per_material_loss

__all__ = ["Adaptive", "CAPACITIES", "FitOptions", "FitProtocol", "FitResult", "LatentAdam", "PaperRMSProp",
           "PlainLBFGS", "SURROGATE_EPS", "default_protocol", "fit_in_processes", "fit_materials", "frozen", "losses_at_own_capacity",
           "material_model", "model_for", "per_material_loss"]


def default_protocol(model: BRDFModel) -> FitProtocol:
    """``PlainLBFGS`` for a model without modules, ``LatentAdam`` (the latent capacity) for one with:
    ``FitOptions()``'s protocol."""
    return FitOptions().protocol_for(model)


def fit_materials(model: BRDFModel, samples: Samples, protocol: FitProtocol | None = None, *,
                  start: MaterialTable | None = None, trained: MaterialTable | None = None,
                  encoder: MaterialEncoder | None = None, seed: int = 0) -> FitResult:
    """Fit every material of ``samples`` with ``model`` frozen by ``protocol`` (default:
    ``default_protocol(model)``); ``start``, ``trained`` and ``encoder`` as ``FitProtocol.fit``
    takes them."""
    protocol = protocol or default_protocol(model)
    return protocol.fit(model, samples, start=start, trained=trained, encoder=encoder, seed=seed)
