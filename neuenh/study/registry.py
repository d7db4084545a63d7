"""Which models the study compares: the enhanced model, the analytical ones, the baselines with
shared weights (trained elsewhere, on the enhanced model's data with its budget:
``orchestrator.baselines``), and the per-material NBRDF network."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..modules import ModuleConfig
from ..models.ggx_residual import RESIDUAL_STATE

__all__ = ["ANALYTICAL", "BASELINES", "Baseline", "ContenderInfo", "EFFICIENCY_CONTENDERS", "ENHANCED",
           "contender_infos"]

ENHANCED = "enhanced"
ANALYTICAL = {"ggx": "GGX", "cook_torrance": "Cook-Torrance", "ward": "Ward"}


@dataclass(frozen=True)
class Baseline:
    """A model with shared weights in a fixed state, trained like the search trained its final state."""

    name: str    # its folder under the baselines directory
    label: str
    family: str  # the colour group of the figures: "residual" or "neural"
    model: str   # a registered model name
    state: str
    hidden: tuple[int, ...] | None = None  # its modules' widths; None for the job spec's

    def module_config(self, spec_default: ModuleConfig) -> ModuleConfig:
        return ModuleConfig(choices=(self.hidden,)) if self.hidden else spec_default

    def bundle_dir(self, baselines: Path) -> Path:
        return baselines / self.name


BASELINES = {b.name: b for b in (
    Baseline("residual-1x", "GGX + residual {32,64,64,16}", "residual", "ggx_residual", RESIDUAL_STATE,
             (32, 64, 64, 16)),
    Baseline("residual-5x", "GGX + residual {32,64,128,128,64}", "residual", "ggx_residual", RESIDUAL_STATE,
             (32, 64, 128, 128, 64)),
    Baseline("all-neural", "all positions neural", "neural", "ggx", "1" * 11),
)}


@dataclass(frozen=True)
class ContenderInfo:
    name: str
    label: str
    family: str  # "enhanced", "analytical", "residual" or "neural"


def contender_infos() -> list[ContenderInfo]:
    """Every model of the study, in the order of its tables."""
    return [ContenderInfo(ENHANCED, "Enhanced GGX (ours)", "enhanced"),
            *(ContenderInfo(n, label, "analytical") for n, label in ANALYTICAL.items()),
            *(ContenderInfo(b.name, b.label, b.family) for b in BASELINES.values()),
            ContenderInfo("nbrdf", "NBRDF (per material)", "neural")]


# The models of the data-efficiency curves (``study.efficiency``): the question is where a shared
# model's prior beats a network fitted from scratch, against the analytical model and the residual MLP.
EFFICIENCY_CONTENDERS = (ENHANCED, "ggx", "residual-1x", "nbrdf")
