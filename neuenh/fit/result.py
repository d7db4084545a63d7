"""What a fit returns (``FitResult``) and the per-material loss of fitted parameters."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import torch

from ..capacities import ANALYTICAL_CAPACITIES
from ..data.samples import Samples
from ..materials import MaterialParams, MaterialTable
from ..model import BRDFModel
from ..train import log_l1, predict


@dataclass
class FitResult:
    """Every material of a fit: its record in ``materials`` (analytical values, latent code and —
    set by a fit that frees them — corrections, capacity and correction count: ``as_params(i)``),
    its mean log-L1 on the fitted samples (``losses``), the protocol that fitted it (``protocol``:
    its name and budgets) and the wall time. ``details``: what the protocol decided per material
    (e.g. cross-validation scores)."""

    materials: MaterialTable
    losses: list[float]
    wall_s: float
    protocol: dict
    details: list[dict] = field(default_factory=list)
    trace: list[tuple[float, float]] = field(default_factory=list)  # (seconds, mean loss), when traced

    @classmethod
    def joined(cls, parts: Sequence[FitResult], wall_s: float, **protocol: Any) -> FitResult:
        """The fits of consecutive groups of materials as one fit of them all, in order (records,
        losses, details; no trace), taking ``wall_s``; its ``protocol`` the first part's with
        ``protocol``'s entries added (e.g. how the materials were split)."""
        return cls(MaterialTable.concat([r.materials for r in parts]), [x for r in parts for x in r.losses], wall_s,
                   {**parts[0].protocol, **protocol}, [d for r in parts for d in r.details])

    def capacity(self, i: int) -> str:
        """Material ``i``'s capacity (``fit.capacity``): ``latent`` unless the fit recorded another."""
        return self.materials.fits[i][1] or "latent"

    def material_model(self, model: BRDFModel, i: int) -> tuple[BRDFModel, MaterialParams]:
        """``material_model`` of material ``i`` of this fit's table."""
        return material_model(model, self.materials, i)

    @property
    def at_own_capacity(self) -> bool:
        """``needs_own_model`` of this fit's table."""
        return needs_own_model(self.materials)

    @property
    def loss(self) -> float:
        return float(sum(self.losses) / len(self.losses))

    def report(self, model: BRDFModel, samples: Samples) -> dict:
        """The fit as plain data (``neuenh fit --json`` and ``POST /v1/jobs/{id}/fit``): per material
        its loss, sample count and record as its capacity's model reads it (``MaterialParams.to_json``:
        parameters, latent code, corrections, capacity, parameter count)."""
        counts = samples.counts().tolist()
        return {"model": model.name, "state": model.state, "protocol": self.protocol,
                "wall_s": round(self.wall_s, 3),
                "materials": [{"name": name, "loss": self.losses[i], "samples": counts[i],
                               **self.material_model(model, i)[1].to_json(digits=6)}
                              for i, name in enumerate(self.materials.names)]}

    def losses_on(self, model: BRDFModel, samples: Samples) -> list[float]:
        """``losses_at_own_capacity`` of this fit's table."""
        return losses_at_own_capacity(model, self.materials, samples)


def analytical_model(model: BRDFModel, capacity: str, seed: int = 0) -> BRDFModel:
    """The analytical model that a capacity of ``ANALYTICAL_CAPACITIES`` fits in ``model``'s place."""
    state = model.analytical_state(keep_alternatives=ANALYTICAL_CAPACITIES[capacity])
    return model if state == model.state else model.enhance(state, seed)


def model_for(model: BRDFModel, params: MaterialParams) -> BRDFModel:
    """The model that evaluates a material fitted with ``model``: for a record of an analytical
    capacity (``ANALYTICAL_CAPACITIES``) that capacity's analytical model, else ``model`` itself."""
    if params.capacity in ANALYTICAL_CAPACITIES:
        return analytical_model(model, params.capacity)
    return model


def material_model(model: BRDFModel, materials: MaterialTable, i: int) -> tuple[BRDFModel, MaterialParams]:
    """Material ``i`` of ``materials`` (fitted with ``model``) as the model that evaluates it and the
    record that model reads (``evaluate``, ``unclipped``, ``specialize``): ``model_for``'s (an
    analytical model for an analytical capacity), else ``model`` (the record's corrections are added
    to its module weights)."""
    params = materials.as_params(i)
    own = model_for(model, params)
    return own, own.used_params(params)


def needs_own_model(materials: MaterialTable) -> bool:
    """Whether some material of ``materials`` needs more than the fitting model and its table row
    (corrections, or an analytical model of its own): then only ``material_model`` evaluates it."""
    return bool(_at_own_capacity(materials))


def _at_own_capacity(materials: MaterialTable) -> list[str]:
    """Each material that ``needs_own_model``, as "name (capacity[, corrected])"."""
    return [f"{name} ({capacity or 'latent'}{', corrected' if corrections else ''})"
            for name, (corrections, capacity, _) in zip(materials.names, materials.fits)
            if corrections or capacity in ANALYTICAL_CAPACITIES]


def losses_at_own_capacity(model: BRDFModel, materials: MaterialTable, samples: Samples) -> list[float]:
    """Each material's mean log-L1 over ``samples`` (same materials, same order), at its own capacity
    and corrections (``material_model``): what a table saved by any fit — a bundle's too — measures."""
    if not needs_own_model(materials):
        return per_material_loss(model, materials, samples)
    out = []
    with torch.no_grad():
        for i in range(len(samples.names)):
            rows = samples.of_material(i)
            if not len(rows):
                out.append(math.nan)
                continue
            own, params = material_model(model, materials, i)
            out.append(float(log_l1(own.unclipped(rows.wi, rows.wo, params), rows.f_r, rows.wi).double().mean()))
    return out


@torch.no_grad()
def per_material_loss(model: BRDFModel, materials: MaterialTable, samples: Samples) -> list[float]:
    """Mean log-L1 of each material over its samples (NaN for a material with none), every
    material read from its table row by ``model`` itself, all in one batch. A table with corrections
    or analytical capacities (``needs_own_model``) is refused: ``model`` alone would measure those
    materials with other weights or another formula than they were fitted with
    (``losses_at_own_capacity`` measures them)."""
    if own := _at_own_capacity(materials):
        raise ValueError(f"materials fitted at their own capacity: {', '.join(own)}; "
                         "measure them with losses_at_own_capacity")
    sums = torch.zeros(len(samples.names), dtype=torch.float64)
    counts = torch.zeros(len(samples.names), dtype=torch.float64)
    for lo in range(0, len(samples), 200_000):
        index = slice(lo, lo + 200_000)
        loss = log_l1(predict(model, materials, samples, index), samples.f_r[index], samples.wi[index])
        sums.index_add_(0, samples.material[index], loss.double())
        counts.index_add_(0, samples.material[index], torch.ones_like(loss, dtype=torch.float64))
    return [float(s / c) if c else math.nan for s, c in zip(sums, counts)]
