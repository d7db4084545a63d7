"""Which models the study compares: the enhanced model, the analytical ones, the baselines with
shared weights (trained elsewhere, on the enhanced model's data with its budget:
``orchestrator.baselines``), and the per-material NBRDF network."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..modules import ModuleConfig
from ..models.ggx_residual import RESIDUAL_STATE

__all__ = ["ANALYTICAL", "BASELINES", "Baseline", "ContenderInfo", "EFFICIENCY_CONTENDERS", "ENCODED", "ENHANCED",
           "ENHANCED_ADAPTIVE", "OTHER_ENHANCED", "contender_infos", "shipped_others"]

# The enhanced model fitted at two capacities (``neuenh.fit.capacity``): the latent code and analytical
# parameters alone (the compact model, a few dozen parameters per material), and the adaptive fit that
# chooses per material, by cross-validation on its fit data, how many module-weight corrections to free.
ENHANCED = "enhanced"
ENHANCED_ADAPTIVE = "enhanced-adaptive"
# the enhanced model's encoder alone (no fit: ``contenders.EncodedContender``), when its bundle has one
ENCODED = "enhanced-encoder"
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
    capacity: str = "latent"  # a model with modules: the fit's capacity (``neuenh.fit.FitOptions.capacity``)


# The paper's other enhancements (its "enhancing other models"): shipped models, each measured beside
# the analytical model it enhances, when they are shipped (``neuenh.pretrained``).
OTHER_ENHANCED = {"enhanced-cook-torrance": ("Enhanced Cook-Torrance", "cook_torrance"),
                  "enhanced-ward": ("Enhanced Ward", "ward")}


def contender_infos(others: tuple[str, ...] = (), encoded: bool = False) -> list[ContenderInfo]:
    """Every model of the study, in the order of its tables; ``others``: the names of
    ``OTHER_ENHANCED`` to include (those shipped); ``encoded``: the enhanced model's encoder alone too."""
    return [ContenderInfo(ENHANCED, "Enhanced GGX (ours), latent", "enhanced"),
            ContenderInfo(ENHANCED_ADAPTIVE, "Enhanced GGX (ours), adaptive", "enhanced", capacity="auto"),
            *([ContenderInfo(ENCODED, "Enhanced GGX, encoder alone (no fit)", "enhanced")] if encoded else []),
            *(ContenderInfo(n, label, "analytical") for n, label in ANALYTICAL.items()),
            *(ContenderInfo(n, OTHER_ENHANCED[n][0], "enhanced") for n in others),
            *(ContenderInfo(b.name, b.label, b.family) for b in BASELINES.values()),
            ContenderInfo("nbrdf", "NBRDF (per material)", "neural")]


def shipped_others() -> tuple[str, ...]:
    """The names of ``OTHER_ENHANCED`` that are shipped."""
    from ..pretrained import shipped_models

    shipped = shipped_models()
    return tuple(n for n in OTHER_ENHANCED if n in shipped)


# The models of the data-efficiency curves (``study.efficiency``): the question is where a shared
# model's prior beats a network fitted from scratch, against the analytical model and the residual MLP.
EFFICIENCY_CONTENDERS = (ENHANCED, ENHANCED_ADAPTIVE, ENCODED, "ggx", "residual-1x", "nbrdf")
