"""The models compared on measured materials (issue 6), behind one small interface.

A :class:`Contender` is fitted to one material's measurements and gives back a
:class:`FittedMaterial`: its raw prediction (what the loss sees, as in training), its BRDF (what
the renderer sees: clipped at 0, zero below either horizon), and its costs — parameters per
material, weights, fit time. Two kinds cover every model of the comparison:

* :class:`GraphContender` — a ``BRDFModel`` in some state with its module weights frozen, fitted
  by a fit protocol (``fit.FitOptions``): the analytical models (GGX, Cook-Torrance, Ward), the
  enhanced GGX (at an adaptive capacity, or the latent code alone), the residual MLPs appended to
  GGX (``models.ggx_residual``) and the all-positions-neural state. Parameters per material: the
  analytical ones, the latent code if a module reads it, and the corrections the fit chose.
* :class:`NBRDFContender` — a network fitted from scratch per material (``nbrdf_fit``); its 675
  weights are per material, so they count as parameters per material, and it has no shared weights.
* :class:`EncodedContender` — a model whose parameters its encoder (``neuenh.encoder``) predicts
  from the measurements in one pass, without any fitting: what an amortised start is worth alone.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Callable

import torch

from ..data.samples import Samples
from ..encoder import MaterialEncoder
from ..fit import FitOptions, fit_materials, per_material_loss
from ..materials import MaterialTable
from ..model import BRDFModel
from .nbrdf_fit import NBRDFConfig, fit_nbrdf

__all__ = ["Contender", "EncodedContender", "FittedMaterial", "GraphContender", "NBRDFContender"]

Directions = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]


@dataclass
class FittedMaterial:
    """One contender fitted to one material."""

    contender: str
    predict: Directions  # raw f_r (n, 3) at float32 (wi, wo): what the loss sees
    brdf: Directions  # f_r (n, 3) for rendering: clipped at 0, zero below either horizon
    fit_loss: float  # mean log-L1 on the fitted samples
    fit_s: float
    params_per_material: int
    shared_weights: int
    capacity: str | None = None  # the fit's capacity (a model with modules)


class Contender(ABC):
    """A model of the comparison. ``name`` is short and stable (file names, tables); ``label`` is
    what a reader sees."""

    name: str
    label: str
    family: str  # "analytical", "enhanced", "residual", "neural"

    @abstractmethod
    def fit(self, samples: Samples, seed: int = 0) -> FittedMaterial:
        """Fit to ``samples`` of exactly one material."""


def _one_material(samples: Samples) -> None:
    if len(samples.names) != 1:
        raise ValueError(f"a contender is fitted to one material at a time, got {len(samples.names)}")


class GraphContender(Contender):
    """``model`` fitted by ``options``' protocol from its ``trained`` materials' starts and its
    ``encoder``'s (``fit.fit_materials``)."""

    def __init__(self, name: str, label: str, family: str, model: BRDFModel,
                 trained: MaterialTable | None = None, options: FitOptions = FitOptions(),
                 encoder: MaterialEncoder | None = None):
        self.name, self.label, self.family = name, label, family
        self.model, self.trained, self.options, self.encoder = model, trained, options, encoder

    def fit(self, samples: Samples, seed: int = 0) -> FittedMaterial:
        _one_material(samples)
        result = fit_materials(self.model, samples, self.options.protocol_for(self.model), seed=seed,
                               trained=self.trained, encoder=self.encoder)
        model, params = result.material_model(self.model, 0)  # its capacity's model and record
        return _fitted(self.name, model, params, result.losses[0], result.wall_s, self.model.n_weights())


class EncodedContender(Contender):
    """``model`` with the parameters ``encoder`` predicts from the fit samples: no fitting at all."""

    def __init__(self, name: str, label: str, family: str, model: BRDFModel, encoder: MaterialEncoder):
        self.name, self.label, self.family = name, label, family
        self.model, self.encoder = model, encoder

    def fit(self, samples: Samples, seed: int = 0) -> FittedMaterial:
        _one_material(samples)
        start = time.perf_counter()
        materials = self.encoder.encode(samples)
        wall_s = time.perf_counter() - start
        (loss,) = per_material_loss(self.model, materials, samples)
        return _fitted(self.name, self.model, self.model.used_params(materials.as_params(0)), loss, wall_s,
                       self.model.n_weights())


def _fitted(name: str, model: BRDFModel, params, fit_loss: float, fit_s: float, shared_weights: int) -> FittedMaterial:
    """``model`` with one material's record (``BRDFModel.used_params``) as a contender's result."""

    @torch.no_grad()
    def predict(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
        return model.unclipped(wi, wo, params)

    brdf = model.specialize(params)  # equals model.evaluate(wi, wo, params), faster
    return FittedMaterial(name, predict, brdf, fit_loss, fit_s, params.n_params, shared_weights, params.capacity)


class NBRDFContender(Contender):
    name, label, family = "nbrdf", "NBRDF (per-material 6-21-21-3)", "neural"

    def __init__(self, config: NBRDFConfig = NBRDFConfig()):
        self.config = config

    def fit(self, samples: Samples, seed: int = 0) -> FittedMaterial:
        _one_material(samples)
        result = fit_nbrdf(samples, self.config, seed=seed)
        net = result.networks[0]

        @torch.no_grad()
        def predict(wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
            return net(wi, wo)

        return FittedMaterial(self.name, predict, net.evaluate, result.losses[0], result.wall_s, net.n_weights(), 0)
