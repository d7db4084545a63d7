"""Analytical BRDF models as graphs, and the registry behind ``get_model``.

>>> from neuenh.models import get_model
>>> ggx = get_model("ggx")
>>> ggx.positions[:6], ggx.param_names
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ..graph import Graph, ModuleConfig
    from ..model import BRDFModel
    from ..params import ParamSpecs

# The models, each a module of this package of the same name whose ``build()`` returns its (Graph,
# ParamSpecs). A module is imported when its model is first built: naming the models (``neuenh fit
# --help``) needs no torch, nor does building a graph (``get_graph``: what a job spec is checked against).
_MODELS = ("ggx", "cook_torrance", "ward", "blinn_phong",
           "ggx_residual")  # baseline: GGX + R, R zero until neural
# Models whose builder offers alternative analytical terms (``build(alternatives=True)``).
_WITH_ALTERNATIVES = ("ggx", "cook_torrance")


def available_models() -> tuple[str, ...]:
    return _MODELS


def models_with_alternatives() -> tuple[str, ...]:
    return _WITH_ALTERNATIVES


def get_graph(name: str, *, alternatives: bool = False) -> tuple[Graph, ParamSpecs]:
    """The analytical model ``name``'s graph and parameter specs (no torch); ``alternatives``: with
    its terms' alternative analytical formulas (``neuenh.models.alternatives``)."""
    if name not in _MODELS:
        raise ValueError(f"unknown model {name!r}; available: {', '.join(_MODELS)}")
    if alternatives and name not in _WITH_ALTERNATIVES:
        raise ValueError(f"model {name!r} offers no alternative terms; those that do: {', '.join(_WITH_ALTERNATIVES)}")
    builder = importlib.import_module(f"{__name__}.{name}").build
    return builder(alternatives=True) if alternatives else builder()


def get_model(
    name: str,
    *,
    state: str | None = None,
    module_config: ModuleConfig | None = None,
    latent_dim: int = 27,
    seed: int = 0,
    alternatives: bool = False,
) -> BRDFModel:
    """The analytical model ``name`` as a graph, in the all-zero state unless ``state`` is given
    (its modules then freshly initialised from ``seed``, sized by ``module_config``, default
    ``ModuleConfig()``). ``alternatives``: offer its terms' alternative analytical formulas as digits
    (``neuenh.models.alternatives``)."""
    from ..graph import ModuleConfig
    from ..model import BRDFModel

    graph, specs = get_graph(name, alternatives=alternatives)
    return BRDFModel(name, graph, specs, state=state, module_config=module_config or ModuleConfig(),
                     latent_dim=latent_dim, seed=seed)


__all__ = ["available_models", "get_graph", "get_model", "models_with_alternatives"]
