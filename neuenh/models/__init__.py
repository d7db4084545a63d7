"""Analytical BRDF models as graphs, and the registry behind ``get_model``.

>>> from neuenh.models import get_model
>>> ggx = get_model("ggx")
>>> ggx.positions[:6], ggx.param_names
"""

from __future__ import annotations

from typing import Callable

from ..graph import Graph
from ..model import BRDFModel
from ..modules import ModuleConfig
from ..params import ParamSpecs
from . import blinn_phong, cook_torrance, ggx, ggx_residual, ward

_BUILDERS: dict[str, Callable[[], tuple[Graph, ParamSpecs]]] = {
    "ggx": ggx.build,
    "cook_torrance": cook_torrance.build,
    "ward": ward.build,
    "blinn_phong": blinn_phong.build,
    "ggx_residual": ggx_residual.build,  # baseline: GGX + R, R zero until neural
}
# Models whose builder offers alternative analytical terms (``build(alternatives=True)``).
_WITH_ALTERNATIVES = ("ggx", "cook_torrance")


def available_models() -> tuple[str, ...]:
    return tuple(_BUILDERS)


def models_with_alternatives() -> tuple[str, ...]:
    return _WITH_ALTERNATIVES


def get_model(
    name: str,
    *,
    state: str | None = None,
    module_config: ModuleConfig = ModuleConfig(),
    latent_dim: int = 27,
    seed: int = 0,
    alternatives: bool = False,
) -> BRDFModel:
    """The analytical model ``name`` as a graph, in the all-zero state unless ``state`` is given
    (its modules then freshly initialised from ``seed``). ``alternatives``: offer its terms'
    alternative analytical formulas as digits (``neuenh.models.alternatives``)."""
    try:
        builder = _BUILDERS[name]
    except KeyError:
        raise ValueError(f"unknown model {name!r}; available: {', '.join(_BUILDERS)}") from None
    if alternatives and name not in _WITH_ALTERNATIVES:
        raise ValueError(f"model {name!r} offers no alternative terms; those that do: {', '.join(_WITH_ALTERNATIVES)}")
    graph, specs = builder(alternatives=True) if alternatives else builder()
    return BRDFModel(
        name, graph, specs, state=state, module_config=module_config, latent_dim=latent_dim, seed=seed
    )


__all__ = ["available_models", "get_model", "models_with_alternatives", "BRDFModel"]
